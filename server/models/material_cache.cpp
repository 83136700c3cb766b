#include "server/models/material_cache.h"

namespace loomlight::models {
namespace {

// The model's name and every parameter's values in the map's (sorted) order, bytes exactly.
void AppendCanonical(const ResolvedMaterial& m, std::string* key) {
  key->append(m.model->name());
  key->push_back('\0');
  for (const auto& [name, values] : m.values) {
    key->append(name);
    key->push_back('\0');
    const uint64_t count = values.size();
    key->append(reinterpret_cast<const char*>(&count), sizeof count);
    key->append(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(double));
  }
}

size_t EntryBytes(const MaterialCache::Entry& e) {
  return sizeof e + e.packed.data.size() * sizeof(double) + (e.transmission ? EntryBytes(*e.transmission) : 0);
}

}  // namespace

std::string MaterialCache::Get(const v1::Material& material, const Registry& registry,
                               std::shared_ptr<const Entry>* out) {
  // The fast path: a request's own bytes, when no unknown field rides in them (then they can only be a
  // resolvable material sent again), find its entry without resolving (~5 us for a preset).
  std::string alias;
  if (!HasUnknownFields(material)) {
    alias.push_back('R');
    material.AppendToString(&alias);
    if (Find(alias, out)) return "";
  }
  ResolvedMaterial top, layer;
  if (std::string error = ResolveComposition(material, registry, &top, &layer); !error.empty())
    return error;  // bad materials are not cached: they are cheap to reject again
  std::string key = "C";
  AppendCanonical(top, &key);
  if (layer.model) {
    key.append("\0+layer\0", 8);
    AppendCanonical(layer, &key);
  }
  if (!Find(key, out)) {
    auto entry = std::make_shared<Entry>();
    entry->model = top.model;
    entry->packed = top.model->Pack(top.values);
    if (layer.model) {
      auto packed_layer = std::make_shared<Entry>();
      packed_layer->model = layer.model;
      packed_layer->packed = layer.model->Pack(layer.values);
      entry->transmission = std::move(packed_layer);
    }
    *out = entry;
    Insert(std::move(key), entry, false);
  }
  if (!alias.empty()) Insert(std::move(alias), *out, true);
  return "";
}

bool MaterialCache::HasUnknownFields(const v1::Material& m) {
  const auto unknown = [](const google::protobuf::Message& message) {
    return !message.GetReflection()->GetUnknownFields(message).empty();
  };
  if (unknown(m)) return true;
  for (const v1::Param& p : m.params())
    if (unknown(p)) return true;
  return m.has_transmission() && HasUnknownFields(m.transmission());
}

bool MaterialCache::Find(const std::string& key, std::shared_ptr<const Entry>* out) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = map_.find(key);
  if (it == map_.end()) return false;
  order_.splice(order_.begin(), order_, it->second.order);
  *out = it->second.entry;
  return true;
}

void MaterialCache::Insert(std::string key, std::shared_ptr<const Entry> entry, bool alias) {
  // Keys count twice (the map's and the order list's copy); an alias counts its entry too (it keeps it alive).
  const size_t bytes = 2 * key.size() + EntryBytes(*entry);
  std::lock_guard<std::mutex> lock(mutex_);
  if (bytes > capacity_bytes_ || map_.count(key)) return;
  while (!order_.empty() && bytes_ + bytes > capacity_bytes_) {
    auto last = map_.find(order_.back());
    bytes_ -= last->second.bytes;
    if (!last->second.alias) --entries_;
    map_.erase(last);
    order_.pop_back();
  }
  order_.push_front(key);
  map_.emplace(std::move(key), Slot{std::move(entry), order_.begin(), bytes, alias});
  bytes_ += bytes;
  if (!alias) ++entries_;
}

size_t MaterialCache::bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return bytes_;
}

size_t MaterialCache::entries() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return entries_;
}

}  // namespace loomlight::models
