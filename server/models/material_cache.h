// The material cache: prepared (resolved and packed) materials for every RPC.
#pragma once

#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>

#include "loomlight/v1/loomlight.pb.h"
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
class MaterialCache {
 public:
  using Entry = PreparedMaterial;
  explicit MaterialCache(size_t capacity_bytes) : capacity_bytes_(capacity_bytes) {}
  // The cached entry, or one packed now ("" on success, else the INVALID_ARGUMENT message).
  std::string Get(const v1::Material& material, const Registry& registry,
                  std::shared_ptr<const Entry>* out);
  size_t bytes() const;
  size_t entries() const;  // packed materials (not counting the request-bytes aliases of the fast path)

 private:
  struct Slot {
    std::shared_ptr<const Entry> entry;
    std::list<std::string>::iterator order;
    size_t bytes;
    bool alias;  // keyed on a request's bytes ("R..."), else on the canonical form ("C...")
  };
  static bool HasUnknownFields(const v1::Material& material);
  bool Find(const std::string& key, std::shared_ptr<const Entry>* out);
  void Insert(std::string key, std::shared_ptr<const Entry> entry, bool alias);

  const size_t capacity_bytes_;
  mutable std::mutex mutex_;
  std::list<std::string> order_;  // keys, most recently used first
  std::unordered_map<std::string, Slot> map_;
  size_t bytes_ = 0;
  size_t entries_ = 0;
};

}  // namespace loomlight::models
