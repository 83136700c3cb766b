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
  ResolvedMaterial top, layer;
  if (std::string error = ResolveComposition(material, registry, &top, &layer); !error.empty())
    return error;  // bad materials are not cached: they are cheap to reject again
  std::string key;
  AppendCanonical(top, &key);
  if (layer.model) {
    key.append("\0+layer\0", 8);
    AppendCanonical(layer, &key);
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = map_.find(key);
    if (it != map_.end()) {
      order_.splice(order_.begin(), order_, it->second.order);
      *out = it->second.entry;
      return "";
    }
  }
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
  // Keys count twice (the map's and the order list's copy).
  const size_t bytes = 2 * key.size() + EntryBytes(*entry);
  std::lock_guard<std::mutex> lock(mutex_);
  if (bytes > capacity_bytes_ || map_.count(key)) return "";
  while (!order_.empty() && bytes_ + bytes > capacity_bytes_) {
    auto last = map_.find(order_.back());
    bytes_ -= last->second.bytes;
    map_.erase(last);
    order_.pop_back();
  }
  order_.push_front(key);
  map_.emplace(std::move(key), Slot{entry, order_.begin(), bytes});
  bytes_ += bytes;
  return "";
}

size_t MaterialCache::bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return bytes_;
}

size_t MaterialCache::entries() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return map_.size();
}

}  // namespace loomlight::models
