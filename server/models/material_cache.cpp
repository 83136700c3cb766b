#include "server/models/material_cache.h"

#include "server/models/tabulated_brdf.h"

#include <cstdio>

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
  size_t values = 0;
  for (const auto& [name, v] : e.values) values += name.size() + v.size() * sizeof(double) + 64;  // + map node
  return sizeof e + values + e.packed.data.size() * (sizeof(double) + sizeof(float)) +
         (e.transmission ? EntryBytes(*e.transmission) : 0);
}

// "model: param value (note)", the setting a part is evaluated at.
std::string DescribeSetting(const MaterialCache::Entry& part, const AccuracyKnob& knob, double value,
                            const std::string& note) {
  char text[96];
  std::snprintf(text, sizeof text, " %g (", value);
  return part.model->name() + ": " + knob.param + text + note + ")";
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
  if (std::string error = Resolve(material, registry, &top, &layer); !error.empty())
    return error;  // bad materials are not cached: they are cheap to reject again
  std::string key = CanonicalKey(top, layer);
  if (!Find(key, out)) {
    auto entry = std::make_shared<Entry>();
    entry->model = top.model;
    entry->packed = top.model->Pack(top.values);
    entry->values = std::move(top.values);
    if (layer.model) {
      // The layer has its own entry, so the variants of one curtain (Render's fidelity choices) share it.
      std::string layer_key = CanonicalKey(layer, {});
      std::shared_ptr<const Entry> shared_layer;
      if (!Find(layer_key, &shared_layer)) {
        auto packed_layer = std::make_shared<Entry>();
        packed_layer->model = layer.model;
        packed_layer->packed = layer.model->Pack(layer.values);
        packed_layer->values = std::move(layer.values);
        shared_layer = std::move(packed_layer);
        Insert(std::move(layer_key), shared_layer, false);
      }
      entry->transmission = std::move(shared_layer);
    }
    entry->own_settings = DescribeOwnSettings(*entry);
    *out = entry;
    Insert(std::move(key), entry, false);
  }
  if (!alias.empty()) Insert(std::move(alias), *out, true);
  return "";
}

std::string MaterialCache::CanonicalKey(const ResolvedMaterial& top, const ResolvedMaterial& layer) {
  std::string key = "C";
  AppendCanonical(top, &key);
  if (layer.model) {
    key.append("\0+layer\0", 8);
    AppendCanonical(layer, &key);
  }
  return key;
}

std::string MaterialCache::Peek(const v1::Material& material, const Registry& registry, const Model** model,
                                std::shared_ptr<const Entry>* cached) {
  cached->reset();
  if (Find(material, cached)) {
    *model = (*cached)->model;
    return "";
  }
  ResolvedMaterial top, layer;
  if (std::string error = Resolve(material, registry, &top, &layer); !error.empty()) return error;
  *model = top.model;
  Find(CanonicalKey(top, layer), cached);
  return "";
}

std::string MaterialCache::Resolve(const v1::Material& material, const Registry& registry, ResolvedMaterial* top,
                                   ResolvedMaterial* layer) {
  batching::Budget::Reservation parse;
  if (const size_t bytes = TextParseBytes(material, registry); parse_budget_ && bytes > 0 &&
                                                               !parse_budget_->TryReserve(bytes, &parse))
    return std::string(kParseBudgetError) + "the server cannot hold this material's text parse (" +
           std::to_string(bytes) + " bytes) now; retry later";
  return ResolveComposition(material, registry, top, layer);
}

bool MaterialCache::Find(const v1::Material& material, std::shared_ptr<const Entry>* out) {
  if (HasUnknownFields(material)) return false;
  std::string alias = "R";
  material.AppendToString(&alias);
  return Find(alias, out);
}

namespace {
// One part's setting when it is not the exact one, or "".
std::string DescribeOwnSetting(const PreparedMaterial& part) {
  const AccuracyKnob knob = part.model->accuracy_knob();
  if (knob.param.empty() || knob.settings.empty()) return "";
  const double current = part.values.at(knob.param).at(0);
  if (current == knob.settings.back()) return "";
  char note[64];
  std::snprintf(note, sizeof note, "the material's own; exact: %g", knob.settings.back());
  return DescribeSetting(part, knob, current, note);
}
}  // namespace

std::string DescribeOwnSettings(const PreparedMaterial& material) {
  std::string text = DescribeOwnSetting(material);
  if (material.transmission)
    if (std::string layer = DescribeOwnSetting(*material.transmission); !layer.empty())
      text += (text.empty() ? "" : "; ") + layer;
  return text;
}

std::string MaterialCache::GetWithin(const v1::Material& material, const Registry& registry, double error_target,
                                     std::shared_ptr<const Entry>* out, std::string* approximation) {
  approximation->clear();
  std::shared_ptr<const Entry> base;
  if (std::string error = Get(material, registry, &base); !error.empty()) return error;
  if (error_target <= 0) {
    *approximation = base->own_settings;
    *out = std::move(base);
    return "";
  }
  v1::Material chosen = material;
  bool changed = false;
  for (const bool layer : {false, true}) {
    const Entry* part = layer ? base->transmission.get() : base.get();
    if (!part) continue;
    const AccuracyKnob knob = part->model->accuracy_knob();
    if (knob.param.empty() || knob.settings.empty()) continue;
    const std::vector<double>& errors = part->KnobErrors();
    size_t s = 0;
    while (s + 1 < errors.size() && !(errors[s] <= error_target)) ++s;  // the last (exact) always qualifies
    char note[96];
    std::snprintf(note, sizeof note, "estimated error %.2g%% for error_target %g", 100 * errors[s], error_target);
    const std::string text = DescribeSetting(*part, knob, knob.settings[s], s + 1 == errors.size() ? "exact" : note);
    *approximation += (approximation->empty() ? "" : "; ") + text;
    if (knob.settings[s] != part->values.at(knob.param).at(0)) {
      chosen = WithParam(chosen, layer, knob.param, knob.settings[s]);
      changed = true;
    }
  }
  if (!changed) {
    *out = std::move(base);
    return "";
  }
  return Get(chosen, registry, out);
}

v1::Material WithParam(const v1::Material& material, bool layer, const std::string& name, double value) {
  v1::Material variant = material;
  v1::Material* target = layer ? variant.mutable_transmission() : &variant;
  v1::Param* param = nullptr;
  for (v1::Param& p : *target->mutable_params())
    if (p.name() == name) param = &p;
  if (!param) param = target->add_params();
  param->set_name(name);
  param->clear_values();
  param->add_values(value);
  return variant;
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
  EvictUntil(bytes);
  order_.push_front(key);
  map_.emplace(std::move(key), Slot{std::move(entry), order_.begin(), bytes, alias});
  bytes_ += bytes;
  if (!alias) ++entries_;
}

void MaterialCache::Clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  map_.clear();
  order_.clear();
  bytes_ = 0;
  entries_ = 0;
}

void MaterialCache::EvictUntil(size_t incoming) {
  while (!order_.empty() && bytes_ + incoming > capacity_bytes_) {
    auto last = map_.find(order_.back());
    bytes_ -= last->second.bytes;
    if (!last->second.alias) --entries_;
    map_.erase(last);
    order_.pop_back();
  }
}

void MaterialCache::ChargeSampler(const Entry& entry) {
  if (entry.SamplerBuilt()) Charge(entry, &Slot::sampler_charged, entry.Sampler().bytes());
}

void MaterialCache::ChargeTable(const Entry& entry) {
  if (entry.TableBuilt() && entry.Table()) Charge(entry, &Slot::table_charged, entry.Table()->bytes());
}

void MaterialCache::Charge(const Entry& entry, bool Slot::*charged, size_t extra) {
  std::lock_guard<std::mutex> lock(mutex_);
  size_t added = 0;
  for (auto& [key, slot] : map_)
    if (slot.entry.get() == &entry && !(slot.*charged)) {
      slot.*charged = true;
      slot.bytes += extra;
      added += extra;
    }
  // Over the bound now: the least recently used go (possibly this entry; its holders keep it alive).
  bytes_ += added;
  EvictUntil(0);
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
