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
// tables) costs far more than resolving it. The key is built from the resolved values, never from the
// request's bytes, so unknown fields, parameter order or a preset spelled out value by value cannot make
// new entries.
class MaterialCache {
 public:
  using Entry = PreparedMaterial;
  explicit MaterialCache(size_t capacity_bytes) : capacity_bytes_(capacity_bytes) {}
  // The cached entry, or one packed now ("" on success, else the INVALID_ARGUMENT message).
  std::string Get(const v1::Material& material, const Registry& registry,
                  std::shared_ptr<const Entry>* out);
  size_t bytes() const;
  size_t entries() const;

 private:
  struct Slot {
    std::shared_ptr<const Entry> entry;
    std::list<std::string>::iterator order;
    size_t bytes;
  };
  const size_t capacity_bytes_;
  mutable std::mutex mutex_;
  std::list<std::string> order_;  // keys, most recently used first
  std::unordered_map<std::string, Slot> map_;
  size_t bytes_ = 0;
};

}  // namespace loomlight::models
