// The Render RPC's fidelity chooser: per object, the cheapest model path whose estimated error stays within
// the request's target (README "Render: fidelity"). Three decisions, each measured on a pilot (a sparse grid
// of pixel centres traced with the render's own code and evaluated on the host with the native build of the
// kernels' source):
// - path: a spatially varying model's BTF where its threads span more than a pixel, else its analytic BRDF
//   (the BTF's mean) when the texture the pixel would average away is within the target;
// - an accuracy parameter of the model (a small table by parameter name, e.g. microcylinder tangent
//   samples): the smallest value whose pilot radiance is within the target of the schema's maximum;
// - transmission: evaluated only when the light reaching the back of the cloth matters;
// - fiber scenes' shadows and ambient occlusion: rays traced through the fibers, or the yarn cross-section's
//   approximations (Wu and Yuksel Sec. 4.1-4.2) when the pilot's radiance with them is within the target of
//   the traced one. The approximations are statistical (a fiber gets the mean visibility at its place in the
//   cross-section, not its own), so the error is that of the pilot's total radiance over a finer grid of its
//   own (kFiberPilotGrid, kFiberPilotRepeats samples per pixel: the fibers' positions vary more than the rays).
// Models are told apart by their properties (spatially_varying(), transmission()) and parameter names,
// never by model name.
#pragma once

#include <string>
#include <vector>

#include "server/models/registry.h"
#include "server/render/shading.h"

namespace loomlight::render {

constexpr double kDefaultErrorTarget = 0.02;  // when a request gives none
constexpr int kPilotGrid = 24;                // pilot rays: 24 x 24 pixel centres
constexpr int kFiberPilotGrid = 64;           // the fiber visibility choice's pilot: 64 x 64 pixels,
constexpr int kFiberPilotRepeats = 2;         // 2 samples each

struct FidelityChoice {
  std::string aspect;  // "path", an accuracy parameter's name, "transmission"
  std::string chosen, full;
  double estimated_error = 0;
  std::string reason;
};

struct ObjectFidelity {
  std::string object, model;
  std::vector<FidelityChoice> choices;
  double estimated_error = 0;     // sum over the choices
  double pixels_per_thread = 0;   // median over the pilot hits; 0 when not spatially varying or not seen
};

// The request's material: its model with its resolved parameters, and whether a curtain layer is behind it.
struct MaterialInfo {
  const models::Model* model = nullptr;
  models::ParamValues values;
  bool layered = false;
};

// Packs the reflection material with one parameter overridden; made by the caller (through its material
// cache, which keeps the result alive for the call). Returns null when that is not possible.
class MaterialVariants {
 public:
  virtual ~MaterialVariants() = default;
  virtual const models::PreparedMaterial* WithParam(const std::string& name, double value) = 0;
  virtual const models::PreparedMaterial* Requested() = 0;  // as the request gave it
};

struct FidelityPlan {
  std::vector<Evaluator> evaluators;   // distinct kernel paths; one batcher job each per chunk
  std::vector<ObjectShading> objects;  // per scene object
  std::vector<ObjectFidelity> fidelity;
  // Fiber scenes: the visibility methods to render with (the setup's, or the chooser's where it chose).
  yarn::ShadowMethod fiber_shadows = yarn::ShadowMethod::kTraced;
  yarn::OcclusionMethod fiber_occlusion = yarn::OcclusionMethod::kTraced;
};

// Fills *plan for every object of setup.scene. Returns "" or why a variant could not be made (internal).
std::string ChooseFidelity(const RenderSetup& setup, const MaterialInfo& material, MaterialVariants& variants,
                           double error_target, bool force_full, FidelityPlan* plan);

// True when the material lets light through the cloth (a layer, or a transmitting model).
inline bool Transmits(const MaterialInfo& m) { return m.layered || (m.model && m.model->transmission()); }

}  // namespace loomlight::render
