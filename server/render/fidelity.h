// The Render RPC's fidelity chooser: per object, the cheapest model path whose estimated error stays within the
// request's target (docs/thumbnails.md "The fidelity chooser"). Its decisions, each measured on a pilot (a sparse
// grid of pixel centres traced with the render's own code and evaluated on the host with the native build of the
// kernels' source):
// - path: a spatially varying model's BTF where its threads span more than a pixel, else its analytic BRDF
//   (the BTF's mean) when the texture the pixel would average away is within the target;
// - the model's accuracy knob (Model::accuracy_knob, e.g. microcylinder tangent samples): the cheapest setting
//   whose pilot radiance is within the target of the exact setting's;
// - transmission: evaluated only when the light reaching the back of the cloth matters;
// - a curtain layer's accuracy knob (its model's accuracy_knob, e.g. the thin layer's scattering orders), chosen
//   as the reflection's, reported as "transmission.<param>";
// - btf_environment: a `btf` asset's environment light folded into it (Sattler et al. Eq. 10) where the fold's
//   estimated error (FoldedEnvironment::EstimateError at the pilot's hits) is within the target, else sampled;
// - fiber scenes' shadows and ambient occlusion: rays traced through the fibers, or the yarn cross-section's
//   approximations (Wu and Yuksel Sec. 4.1-4.2) when the pilot's radiance with them is within the target of
//   the traced one. The approximations are statistical (a fiber gets the mean visibility at its place in the
//   cross-section, not its own), so the error is that of the pilot's total radiance over a finer grid of its
//   own (kFiberPilotGrid, kFiberPilotRepeats samples per pixel: the fibers' positions vary more than the rays).
// Models are told apart by their declared properties (spatially_varying(), transmission(), accuracy_knob()),
// never by model or parameter name.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "server/models/material_cache.h"
#include "server/models/registry.h"
#include "server/render/folded_environment.h"
#include "server/render/shading.h"

namespace loomlight::render {

constexpr double kDefaultErrorTarget = 0.02;  // when a request gives none
constexpr int kPilotGrid = 24;                // pilot rays: 24 x 24 pixel centres
constexpr double kMaxBrdfPixelsPerThread = 1;  // the BRDF's rung: only where threads are narrower than a pixel
constexpr int kFiberPilotGrid = 64;           // the fiber visibility choice's pilot: 64 x 64 pixels,
constexpr int kFiberPilotRepeats = 2;         // 2 samples each

struct FidelityChoice {
  std::string aspect;  // "path", an accuracy knob's parameter, "transmission", "transmission.<layer knob>"
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

// The requested material and its variants with accuracy knobs set, packed for the chooser (and then the render);
// each returns null when that is not possible.
class MaterialVariants {
 public:
  // One parameter set to a value; an empty param leaves that part as the request gave it.
  struct Setting {
    std::string param;
    double value = 0;
  };
  virtual ~MaterialVariants() = default;
  virtual const models::PreparedMaterial* Requested() = 0;  // as the request gave it
  // The material with one parameter of its own and one of its curtain layer set.
  virtual const models::PreparedMaterial* WithSettings(const Setting& reflection, const Setting& layer) = 0;
};

// Variants packed through a material cache (which validates them, and packs a layer shared by several variants
// once); each stays alive as long as this object.
class CachedVariants final : public MaterialVariants {
 public:
  CachedVariants(const v1::Material& material, const models::Registry& registry, models::MaterialCache& cache)
      : registry_(registry), cache_(cache), base_(material) {}
  const models::PreparedMaterial* Requested() override { return Get(base_); }
  const models::PreparedMaterial* WithSettings(const Setting& reflection, const Setting& layer) override;

 private:
  const models::PreparedMaterial* Get(const v1::Material& material);
  const models::Registry& registry_;
  models::MaterialCache& cache_;
  const v1::Material base_;
  std::vector<std::shared_ptr<const models::PreparedMaterial>> kept_;
};

struct FidelityPlan {
  std::vector<Evaluator> evaluators;   // distinct kernel paths; one batcher job each per chunk
  std::vector<ObjectShading> objects;  // per scene object
  std::vector<ObjectFidelity> fidelity;
  // Fiber scenes: the visibility methods to render with (the setup's, or the chooser's where it chose).
  yarn::ShadowMethod fiber_shadows = yarn::ShadowMethod::kTraced;
  yarn::OcclusionMethod fiber_occlusion = yarn::OcclusionMethod::kTraced;
  // Fiber scenes: AUTO's thinned geometry was further from full detail than the target; the render uses the
  // setup's full_detail_fibers (and visibility) instead of scene.fibers.
  bool fiber_full_detail = false;
};

// printf into a string, for the fidelity report's reasons (at most 255 bytes).
std::string Format(const char* format, ...) __attribute__((format(printf, 1, 2)));

// The index of evaluator `e` among *evaluators, appended when it is not there yet.
int EvaluatorIndex(std::vector<Evaluator>* evaluators, const Evaluator& e);

// What one object wears: its material and that material's variants.
struct ObjectMaterial {
  MaterialInfo info;
  MaterialVariants* variants = nullptr;
};

// Fills *plan for every object of setup.scene (materials: one per object), its pilots on up to `threads`
// threads. A spatially varying material's path is chosen per pixel: the BRDF where a pixel's footprint spans
// so many threads that, over the pilot's hits that far away, the texture a pixel keeps stays within the target
// of the BTF, the BTF nearer (ObjectShading::near_footprint). Returns "" or why a variant could not be made
// (internal).
std::string ChooseFidelity(const RenderSetup& setup, const std::vector<ObjectMaterial>& materials,
                           double error_target, bool force_full, FidelityPlan* plan, int threads = 1);
// Every object wearing one material.
std::string ChooseFidelity(const RenderSetup& setup, const MaterialInfo& material, MaterialVariants& variants,
                           double error_target, bool force_full, FidelityPlan* plan, int threads = 1);

// btf_environment, where it may fold (FOLDED, or AUTO): the environment folded into every object's `btf`
// material (`cache`'s fold for this setup when it has one, else built and kept there; may be null), its error
// estimated per object at the pilot's hits (FoldedEnvironment::EstimateError; kept with the fold per image
// size), and per object the choice: FOLDED (`requested`) keeps every fold; AUTO an object's when its estimate is
// within the target (not when the pilot missed it). *out folds only the objects that keep theirs (null: none);
// (*choices)[o] is each folded-capable object's report (aspect "btf_environment"; the others' stay empty).
// `admit` is asked for a new fold's bytes first. Returns "" or why not (*refused: the memory budget).
std::string FoldEnvironment(const RenderSetup& setup, const std::vector<FoldedEnvironment::Material>& materials,
                            FoldCache* cache, double error_target, bool requested, int threads,
                            const std::function<bool()>& stop, const std::function<bool(uint64_t)>& admit,
                            bool* refused, std::shared_ptr<const FoldedEnvironment>* out,
                            std::vector<FidelityChoice>* choices);

// True when the material lets light through the cloth (a layer, or a transmitting model).
inline bool Transmits(const MaterialInfo& m) { return m.layered || (m.model && m.model->transmission()); }

}  // namespace loomlight::render
