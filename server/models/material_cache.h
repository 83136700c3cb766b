// The material cache: prepared (resolved and packed) materials for every RPC.
#pragma once

#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <unordered_map>

#include "loomlight/v1/loomlight.pb.h"
#include "server/batching/budget.h"
#include "server/models/material.h"
#include "server/models/material_plan.h"
#include "server/models/registry.h"

namespace loomlight::models {

// Packed materials by the canonical form of their resolved parameters (model name and every parameter's
// values, in order), least recently used first out, bounded in bytes: clients send the same few materials
// over and over, and packing one (the tangent curve sampled with cos/sin, a thin layer's adding-doubling
// tables) costs far more than resolving it. Entries are keyed on the resolved values, so unknown fields,
// parameter order or a preset spelled out value by value cannot make new entries. A request with no unknown
// field also gets an alias keyed on its own bytes, so the same request again skips resolving (~5 us); the
// aliases share the LRU order and the byte bound.
// How Get, GetWithin and Peek's error starts when the memory budget cannot hold a material's text parse now
// (MaterialCache::ChargeParsesTo): the API answers it RESOURCE_EXHAUSTED, every other error INVALID_ARGUMENT.
inline constexpr std::string_view kParseBudgetError = "memory budget: ";

class MaterialCache {
 public:
  using Entry = PreparedMaterial;
  explicit MaterialCache(size_t capacity_bytes) : capacity_bytes_(capacity_bytes) {}
  // Charges each material's text parses (a WIF draft's; TextParseBytes) to `budget` while they run, so that
  // many large drafts at once are refused rather than held; null (the default): nothing is charged.
  void ChargeParsesTo(batching::Budget* budget) { parse_budget_ = budget; }
  // The cached entry, or one packed now ("" on success, else the INVALID_ARGUMENT message).
  std::string Get(const v1::Material& material, const Registry& registry,
                  std::shared_ptr<const Entry>* out);
  // The cached entry when the request's own bytes find it (the fast path; no resolving, no packing).
  bool Find(const v1::Material& material, std::shared_ptr<const Entry>* out);
  // Checks a material without packing it (cheap enough for a gRPC thread): *model is its model, *cached its
  // entry when the cache has it, else null (a worker packs it later with Get). "" or the INVALID_ARGUMENT
  // message.
  std::string Peek(const v1::Material& material, const Registry& registry, const Model** model,
                   std::shared_ptr<const Entry>* cached);
  // As Get, with each part's accuracy knob (Model::accuracy_knob; the material and its curtain layer) set to
  // the cheapest setting whose estimated error (PreparedMaterial::KnobErrors) is within error_target (> 0);
  // with error_target 0 the material's own settings. *approximation describes the settings of every part
  // not at its exact setting, with their estimated errors when a target was given ("" when none is).
  std::string GetWithin(const v1::Material& material, const Registry& registry, double error_target,
                        std::shared_ptr<const Entry>* out, std::string* approximation);
  // Counts an entry's sampling table (PreparedMaterial::Sampler, built on its first use by a render or a Sample
  // call, which then call this) in its bytes, evicting the least recently used entries if that passes the bound.
  void ChargeSampler(const Entry& entry);
  // The same for its tabulated BRDF (PreparedMaterial::Table, built by a render that takes that rung).
  void ChargeTable(const Entry& entry);
  // Drops every entry: what a material names changed (a BTF asset was replaced or deleted), so neither a
  // request's bytes nor its resolved values may find the old packing.
  void Clear();
  size_t bytes() const;
  size_t entries() const;  // packed materials (not counting the request-bytes aliases of the fast path)

 private:
  struct Slot {
    std::shared_ptr<const Entry> entry;
    std::list<std::string>::iterator order;
    size_t bytes;
    bool alias;  // keyed on a request's bytes ("R..."), else on the canonical form ("C...")
    bool sampler_charged = false;  // bytes include the entry's sampling table
    bool table_charged = false;    // and its tabulated BRDF
  };
  // Adds `extra` bytes to every slot of `entry` whose `charged` flag is unset (setting it), then evicts.
  void Charge(const Entry& entry, bool Slot::*charged, size_t extra);
  void EvictUntil(size_t incoming);  // under the lock: drops entries until `incoming` more bytes fit
  static bool HasUnknownFields(const v1::Material& material);
  static std::string CanonicalKey(const ResolvedMaterial& top, const ResolvedMaterial& layer);
  bool Find(const std::string& key, std::shared_ptr<const Entry>* out);
  // ResolveComposition with its text parses charged to parse_budget_.
  std::string Resolve(const v1::Material& material, const Registry& registry, ResolvedMaterial* top,
                      ResolvedMaterial* layer);
  void Insert(std::string key, std::shared_ptr<const Entry> entry, bool alias);

  const size_t capacity_bytes_;
  batching::Budget* parse_budget_ = nullptr;
  mutable std::mutex mutex_;
  std::list<std::string> order_;  // keys, most recently used first
  std::unordered_map<std::string, Slot> map_;
  size_t bytes_ = 0;
  size_t entries_ = 0;
};

// The accuracy-knob settings of the material and its layer that are not exact ("model: param value (the
// material's own; exact: x)", "; "-joined), or "": what EvaluateResponse.approximation says without a target.
std::string DescribeOwnSettings(const PreparedMaterial& material);

// The material with parameter `name` set to `value`, on the material itself or (layer) on its curtain layer.
v1::Material WithParam(const v1::Material& material, bool layer, const std::string& name, double value);

}  // namespace loomlight::models
