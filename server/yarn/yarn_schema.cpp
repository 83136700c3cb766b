#include "server/yarn/yarn_schema.h"

#include <cmath>
#include <cstdio>
#include <variant>

#include "server/models/quote.h"

namespace loomlight::yarn {
namespace {

using Field = std::variant<int YarnParams::*, double YarnParams::*, bool YarnParams::*>;

struct Entry {
  YarnParamSpec spec;
  Field field;
};

const std::vector<Entry>& Entries() {
  static const std::vector<Entry> entries = [] {
    const double lo = kMinLength, hi = kMaxLength;
    std::vector<Entry> e = {
        {{"plies", true, "1", 1, kMaxPlies, "K: plies twisted into the yarn"}, &YarnParams::plies},
        {{"fibers_per_ply", true, "1", 1, kMaxFibersPerPly,
          "fibers in each ply, including those its core fiber stands for"},
         &YarnParams::fibers_per_ply},
        {{"yarn_radius", false, "", lo, hi, "R_ply: ply centres sit at yarn_radius / 2 from the yarn centre"},
         &YarnParams::yarn_radius},
        {{"ellipse_n", false, "", lo, hi, "e_N: the ply's semi-axis towards the yarn centre (the short one)"},
         &YarnParams::ellipse_n},
        {{"ellipse_b", false, "", lo, hi, "e_B: the ply's other semi-axis (the long one)"}, &YarnParams::ellipse_b},
        {{"alpha", false, "", lo, hi, "fiber twist pitch around the ply centre (length per turn)"},
         &YarnParams::alpha},
        {{"alpha_yarn", false, "", lo, hi, "ply twist pitch around the yarn centre (length per turn)"},
         &YarnParams::alpha_yarn},
        {{"counter_twist", true, "1", 0, 1, "1: fibers turn in their ply the opposite way to the plies in the yarn"},
         &YarnParams::counter_twist},
        {{"eps", false, "1", 0, 1, "D(R)'s floor: the density at the ply's rim"}, &YarnParams::eps},
        {{"beta", false, "1", 0, kMaxBeta, "D(R)'s exponent: larger packs fibers towards the ply centre"},
         &YarnParams::beta},
        {{"s", false, "1", 0, kMaxS, "Eq. 2: the migration phase runs s times as fast as the twist angle"},
         &YarnParams::s},
        {{"rho_min", false, "1", 0, 1, "Eq. 2: the smallest radius multiplier (at most rho_max)"},
         &YarnParams::rho_min},
        {{"rho_max", false, "1", 0, 1, "Eq. 2: the largest radius multiplier, in (0, 1]"}, &YarnParams::rho_max},
        {{"hair_density", false, "1/length", 0, kMaxDensity, "hair flyaways per unit length of yarn per ply"},
         &YarnParams::hair_density},
        {{"loop_density", false, "1/length", 0, kMaxDensity, "loop flyaways per unit length of yarn per ply"},
         &YarnParams::loop_density},
        {{"fiber_width", false, "", lo, hi,
          "a regular fiber's diameter (presets: 2 sqrt(e_N e_B / fibers_per_ply), the ply's area per fiber)"},
         &YarnParams::fiber_width},
    };
    return e;
  }();
  return entries;
}

const Entry* Find(std::string_view name) {
  for (const Entry& e : Entries())
    if (e.spec.name == name) return &e;
  return nullptr;
}

using models::Number;

}  // namespace

const std::vector<YarnParamSpec>& YarnParamSpecs() {
  static const std::vector<YarnParamSpec> specs = [] {
    std::vector<YarnParamSpec> s;
    for (const Entry& e : Entries()) s.push_back(e.spec);
    return s;
  }();
  return specs;
}

double GetYarnParam(const YarnParams& p, std::string_view name) {
  const Entry* e = Find(name);
  if (e == nullptr) return 0;
  return std::visit([&](auto member) { return double(p.*member); }, e->field);
}

std::string SetYarnParam(std::string_view name, double value, YarnParams* p) {
  const Entry* e = Find(name);
  if (e == nullptr) return "params: unknown yarn parameter " + models::Quote(name);
  const YarnParamSpec& s = e->spec;
  // The negated comparison also refuses NaN.
  if (!(value >= s.min && value <= s.max))
    return s.name + ": is " + Number(value) + ", must be a finite number in [" + Number(s.min) + ", " +
           Number(s.max) + "]";
  if (s.integer && value != std::floor(value)) return s.name + ": is " + Number(value) + ", must be an integer";
  std::visit([&](auto member) { p->*member = static_cast<std::remove_reference_t<decltype(p->*member)>>(value); },
             e->field);
  return "";
}

}  // namespace loomlight::yarn
