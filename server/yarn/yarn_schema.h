// The procedural yarn's parameters by name, for a service that lists them and sets them from requests (the
// way models declare theirs): one table ties each name to its YarnParams field, its range and its meaning.
// ValidateYarnParams stays the judge of a whole parameter set (its cross-field rules); the table's ranges are
// the per-field ones it enforces.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "server/yarn/yarn.h"

namespace loomlight::yarn {

struct YarnParamSpec {
  std::string name;
  bool integer = false;  // an integer (or a 0/1 flag) rather than a real
  std::string unit;      // "" for the presets' length unit (see curve.h), "1" for pure numbers
  double min = 0;
  double max = 0;
  std::string description;
};

// Every settable parameter (the seed is not one: requests carry it as an integer of its own), in a fixed order.
const std::vector<YarnParamSpec>& YarnParamSpecs();

// The value of a named parameter in p (the name must be one of YarnParamSpecs()).
double GetYarnParam(const YarnParams& p, std::string_view name);

// Sets one parameter. Returns "" or "name: reason" (unknown name, a non-finite value, out of the table's range,
// or not an integer where one is needed). Cross-field rules are ValidateYarnParams'.
std::string SetYarnParam(std::string_view name, double value, YarnParams* p);

}  // namespace loomlight::yarn
