#include "server/render/fidelity.h"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <numbers>

#include "server/runtime/parallel_for.h"
#include "server/yarn/fiber_scene.h"

namespace loomlight::render {

std::string Format(const char* format, ...) {
  char buffer[256];
  va_list args;
  va_start(args, format);
  std::vsnprintf(buffer, sizeof buffer, format, args);
  va_end(args);
  return buffer;
}

namespace {

struct Knob {
  std::string aspect, name;        // the report's aspect; the parameter ("": no knob)
  std::vector<double> candidates;  // cheapest first, all below full
  double full = 0;
};

// The model's declared accuracy knob (models::AccuracyKnob), reported as aspect_prefix + its parameter, or a
// knob with an empty name.
Knob FindKnob(const models::Model& model, const std::string& aspect_prefix) {
  const models::AccuracyKnob declared = model.accuracy_knob();
  if (declared.param.empty() || declared.settings.empty()) return {};
  Knob knob{aspect_prefix + declared.param, declared.param, declared.settings, declared.settings.back()};
  knob.candidates.pop_back();
  return knob;
}

// The reflection material's knob and its curtain layer's.
struct Knobs {
  Knob reflection, layer;
};

// One object's modelling choice during the search.
struct Config {
  bool btf = false;
  double knob = 0, layer_knob = 0;
  bool transmission = false;
};

MaterialVariants::Setting SettingOf(const Knob& knob, double value) {
  return knob.name.empty() ? MaterialVariants::Setting{} : MaterialVariants::Setting{knob.name, value};
}



// The evaluator and shading of one object under `config`; false when a variant cannot be packed.
bool MakeShading(const MaterialInfo& m, MaterialVariants& variants, const Knobs& knobs, const Config& config,
                 std::vector<Evaluator>* evaluators, ObjectShading* out) {
  const models::PreparedMaterial* material = variants.WithSettings(SettingOf(knobs.reflection, config.knob),
                                                                   SettingOf(knobs.layer, config.layer_knob));
  if (!material) return false;
  out->evaluator = EvaluatorIndex(
      evaluators, {material, config.btf && m.model->spatially_varying(), config.transmission && Transmits(m)});
  return true;
}

// The pilot: a grid of pixel centres traced once, grouped by the object they hit.
class Pilot {
 public:
  explicit Pilot(const RenderSetup& setup) : by_object_(setup.scene.objects.size()) {
    const int nx = std::min(kPilotGrid, setup.width), ny = std::min(kPilotGrid, setup.height);
    ShadingPoint point;
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        // Its own points (environment samples), apart from every pixel sample's.
        const SamplePoints points(setup.seed ^ 0x70696c6f74ull, uint64_t(j) * nx + i, 0);
        TraceSample(setup, (i + 0.5) * setup.width / nx, (j + 0.5) * setup.height / ny, points, &point);
        if (point.object >= 0) by_object_[point.object].push_back(point);
      }
  }
  const std::vector<ShadingPoint>& points(int object) const { return by_object_[object]; }

 private:
  std::vector<std::vector<ShadingPoint>> by_object_;
};

// Adds each query's weight x f (R + G + B), evaluated on the host, to (*radiance)[its tag].
void AddHostRadiance(const std::vector<Evaluator>& evaluators, const std::vector<QueryBucket>& buckets,
                     std::vector<double>* radiance) {
  std::vector<double> f;
  for (size_t e = 0; e < evaluators.size(); ++e) {
    const QueryBucket& b = buckets[e];
    if (b.size() == 0) continue;
    EvaluateOnHost(evaluators[e], b, &f);
    for (size_t q = 0; q < b.size(); ++q)
      for (int c = 0; c < 3; ++c) {
        const double value = double(b.weight[3 * q + c]) * f[3 * q + c];
        if (std::isfinite(value)) (*radiance)[b.tag[q]] += value;
      }
  }
}

// Radiance (R + G + B) of each pilot point of one object under `config`, evaluated on the host.
bool PilotRadiance(const std::vector<ShadingPoint>& points, const MaterialInfo& m, MaterialVariants& variants,
                   const Knobs& knobs, const Config& config, std::vector<double>* radiance) {
  std::vector<Evaluator> evaluators;
  ObjectShading shading;
  if (!MakeShading(m, variants, knobs, config, &evaluators, &shading)) return false;
  std::vector<QueryBucket> buckets(evaluators.size());
  radiance->assign(points.size(), 0.0);
  for (size_t i = 0; i < points.size(); ++i) {
    const Rgb direct = AppendQueries(points[i], shading, evaluators, static_cast<uint32_t>(i), &buckets);
    (*radiance)[i] = direct.x + direct.y + direct.z;
  }
  AddHostRadiance(evaluators, buckets, radiance);
  return true;
}

// sum |a - b| w / sum |b| (weights w default 1): the relative L1 difference of two pilot renders.
double RelativeL1(const std::vector<double>& a, const std::vector<double>& b, const std::vector<double>* w = nullptr) {
  double diff = 0, total = 0;
  for (size_t i = 0; i < b.size(); ++i) {
    diff += std::fabs(a[i] - b[i]) * (w ? (*w)[i] : 1.0);
    total += std::fabs(b[i]);
  }
  return total > 0 ? diff / total : 0.0;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

std::string KnobText(double v) { return Format("%g", v); }

// The pilot's hits, in image order.
std::vector<ShadingPoint> PilotHits(const RenderSetup& setup) {
  const Pilot pilot(setup);
  std::vector<ShadingPoint> hits;
  for (size_t o = 0; o < setup.scene.objects.size(); ++o)
    hits.insert(hits.end(), pilot.points(int(o)).begin(), pilot.points(int(o)).end());
  return hits;
}

// The btf_environment choice per object the fold covers, from its estimated errors (*errors, estimated here at
// the pilot's hits when empty). False when stopped.
bool ChooseFoldedEnvironment(const RenderSetup& setup, const FoldedEnvironment& fold,
                             const std::vector<FoldedEnvironment::Material>& materials, double error_target,
                             bool requested, int threads, const std::function<bool()>& stop,
                             std::vector<double>* errors, std::vector<FidelityChoice>* choices,
                             std::vector<bool>* keep) {
  const size_t objects = setup.scene.objects.size();
  choices->assign(objects, {});
  keep->assign(objects, false);
  if (errors->empty()) *errors = fold.EstimateError(setup, materials, PilotHits(setup), threads, stop);
  if (errors->empty()) return false;
  const std::vector<double>& error = *errors;
  for (size_t o = 0; o < objects; ++o) {
    if (!fold.Covers(int(o))) continue;
    const double e = o < error.size() ? error[o] : -1.0;
    const bool within = e >= 0 && e <= error_target;
    (*keep)[o] = requested || within;
    FidelityChoice& c = (*choices)[o];
    c.aspect = "btf_environment";
    c.full = "sampled";
    c.chosen = (*keep)[o] ? "folded" : "sampled";
    c.estimated_error = (*keep)[o] ? std::max(e, 0.0) : 0.0;
    const std::string estimate =
        e < 0 ? std::string("no pilot hit to estimate its error")
              : Format("estimated error %.2g (the pilot's reflected environment light against each hit's own fold "
                       "from %d x %d cells, relative L1)",
                       e, FoldedEnvironment::kReferenceCellsAround, FoldedEnvironment::kReferenceCellsDown);
    c.reason = (*keep)[o] ? fold.Describe(int(o)) + "; " + estimate + (requested ? "; requested" : "")
               : e < 0    ? "btf_environment AUTO: sampled, as the pilot rays missed the object (" + estimate + ")"
                          : Format("btf_environment AUTO: sampled, as the fold's %s is over the target %g",
                                   estimate.c_str(), error_target);
  }
  return true;
}

// Sets one knob (the `setting` of *chosen) to its cheapest setting whose pilot radiance is within the target of
// its full setting's, the rest of *chosen as it is, and says so in *choice. False when a variant cannot be packed.
bool ChooseKnob(const std::vector<ShadingPoint>& points, const MaterialInfo& m, MaterialVariants& variants,
                const Knobs& knobs, const Knob& knob, double Config::*setting, double target, Config* chosen,
                FidelityChoice* choice) {
  std::vector<double> reference, candidate;
  if (!PilotRadiance(points, m, variants, knobs, *chosen, &reference)) return false;
  choice->reason = Format("no cheaper %s is within the target of %g", knob.name.c_str(), knob.full);
  for (double value : knob.candidates) {
    Config cheaper = *chosen;
    cheaper.*setting = value;
    if (!PilotRadiance(points, m, variants, knobs, cheaper, &candidate)) return false;
    const double error = RelativeL1(candidate, reference);
    if (error <= target) {
      chosen->*setting = value;
      choice->chosen = KnobText(value);
      choice->estimated_error = error;
      choice->reason = Format("%s %g: pilot radiance within %.2g of %g (relative L1)", knob.name.c_str(), value,
                              error, knob.full);
      break;
    }
  }
  return true;
}

// The fiber object's total pilot radiance (R + G + B over every pilot pixel and repeat) with the given
// visibility methods: each pilot pixel centre traced kFiberPilotRepeats times (own random streams: the light and
// occlusion directions), shaded on the host.
double FiberPilotTotal(RenderSetup setup, yarn::ShadowMethod shadows, yarn::OcclusionMethod occlusion,
                       const std::vector<Evaluator>& evaluators, const ObjectShading& shading, int* hits) {
  setup.fiber_shadows = shadows;
  setup.fiber_occlusion = occlusion;
  const int nx = std::min(kFiberPilotGrid, setup.width), ny = std::min(kFiberPilotGrid, setup.height);
  std::vector<QueryBucket> buckets(evaluators.size());
  ShadingPoint point;
  *hits = 0;
  for (int k = 0; k < kFiberPilotRepeats; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        const SamplePoints points(setup.seed ^ 0x66696265725full, uint64_t(j) * nx + i, k);
        TraceSample(setup, (i + 0.5) * setup.width / nx, (j + 0.5) * setup.height / ny, points, &point);
        if (point.object != setup.scene.fiber_object) continue;
        ++*hits;
        AppendQueries(point, shading, evaluators, 0, &buckets);
      }
  std::vector<double> total(1, 0.0);  // every query tagged 0
  AddHostRadiance(evaluators, buckets, &total);
  return total[0];
}

// A pilot pass's radiance total and the fiber hits it had.
struct PilotTotal {
  double total = 0;
  int hits = 0;
};

// AUTO's thinned fibers (Eq. 4) against full detail: the pilot's radiance through each, shadows and occlusion
// traced in both (the geometry's own error, apart from the visibility approximations'). Fills the geometry
// choice's estimate and reason; true where the thinning is over the target and full detail is to be rendered.
// *kept: the traced pass of the geometry the render keeps (the visibility chooser's reference, not traced
// twice). Measured on the distant woven patch (cotton): the thinned fibers' R highlight, the core's one helix of
// directions against the spread of the fibers', put the image 20% above full detail's.
bool ChooseFiberGeometry(const RenderSetup& thinned, const RenderSetup& full, const std::vector<Evaluator>& evaluators,
                         const ObjectShading& shading, double target, int threads, FidelityChoice* geometry,
                         PilotTotal* kept) {
  using yarn::OcclusionMethod;
  using yarn::ShadowMethod;
  PilotTotal pass[2];  // thinned, full
  runtime::ParallelFor(2, threads, {}, [&](size_t i) {
    pass[i].total = FiberPilotTotal(i == 0 ? thinned : full, ShadowMethod::kTraced, OcclusionMethod::kTraced,
                                    evaluators, shading, &pass[i].hits);
  });
  *kept = pass[0];
  if (pass[1].hits == 0 || pass[1].total <= 0) {
    geometry->reason += "; no full-detail fiber hit by the pilot rays: kept";
    return false;
  }
  const double error = std::fabs(pass[0].total - pass[1].total) / pass[1].total;
  const bool over = error > target;
  geometry->reason += Format("; pilot radiance %.2g from full detail (%d and %d pilot samples), %s", error,
                             pass[0].hits, pass[1].hits, over ? "over the target: full detail" : "within the target");
  if (!over) {
    geometry->estimated_error = error;
    return false;
  }
  *kept = pass[1];
  geometry->chosen = "full";
  geometry->reason += Format(", %lld fiber curves", static_cast<long long>(full.scene.fibers->stats().curves));
  return true;
}

// The fiber scene's shadow and occlusion methods: the request's, or (where it left them to the chooser) the
// approximation whose pilot radiance is closest to the traced one, when within the target. `traced`: the traced
// pass when the caller has it already (null: traced here).
void ChooseFiberVisibility(const RenderSetup& setup, const std::vector<Evaluator>& evaluators,
                           const ObjectShading& shading, double target, bool force_full, int threads,
                           const PilotTotal* traced, FidelityPlan* plan, ObjectFidelity* out) {
  using yarn::OcclusionMethod;
  using yarn::ShadowMethod;
  FidelityChoice shadows{"fiber_shadows", yarn::ToString(setup.fiber_shadows), "traced", 0, "requested"};
  FidelityChoice occlusion{"fiber_occlusion", yarn::ToString(setup.fiber_occlusion), "traced", 0, "requested"};
  plan->fiber_shadows = setup.fiber_shadows;
  plan->fiber_occlusion = setup.fiber_occlusion;
  const bool have = setup.scene.fiber_visibility != nullptr;
  if (force_full || !have) {
    plan->fiber_shadows = ShadowMethod::kTraced;
    plan->fiber_occlusion = OcclusionMethod::kTraced;
    shadows.chosen = occlusion.chosen = "traced";
    shadows.reason = occlusion.reason = force_full ? "force_full_fidelity" : "no cross-section approximation";
  } else {
    // The pilot's passes, traced and each approximation, are independent: they run at once on `threads`
    // threads, each pass on one (its total is the serial one bit for bit). Set-up of a 128 x 128 woven patch
    // went from 34 to 22 ms.
    struct Pass {
      ShadowMethod shadows;
      OcclusionMethod occlusion;
      double total = 0;
      int hits = 0;
    };
    std::vector<Pass> passes = {{ShadowMethod::kTraced, OcclusionMethod::kTraced},
                                {ShadowMethod::kSlices, OcclusionMethod::kTraced}};
    if (setup.ambient > 0) {
      passes.push_back({ShadowMethod::kTraced, OcclusionMethod::kTexture});
      passes.push_back({ShadowMethod::kTraced, OcclusionMethod::kDistance});
    }
    if (traced) {
      passes[0].total = traced->total;
      passes[0].hits = traced->hits;
    }
    const size_t first = traced ? 1 : 0;
    runtime::ParallelFor(passes.size() - first, threads, {}, [&](size_t k) {
      Pass& p = passes[first + k];
      p.total = FiberPilotTotal(setup, p.shadows, p.occlusion, evaluators, shading, &p.hits);
    });
    const double traced = passes[0].total;
    const int hits = passes[0].hits;
    const auto error_of = [&](ShadowMethod s, OcclusionMethod o) {
      for (const Pass& p : passes)
        if (p.shadows == s && p.occlusion == o) return traced > 0 ? std::fabs(p.total - traced) / traced : 0.0;
      return 0.0;
    };
    const std::string pilot = Format("%d pilot samples", hits);
    if (hits == 0) {
      if (setup.choose_fiber_shadows) plan->fiber_shadows = ShadowMethod::kTraced;
      if (setup.choose_fiber_occlusion) plan->fiber_occlusion = OcclusionMethod::kTraced;
      shadows.reason = occlusion.reason = "no fiber hit by the pilot rays: traced";
    } else {
      const double slices = error_of(ShadowMethod::kSlices, OcclusionMethod::kTraced);
      if (setup.choose_fiber_shadows) plan->fiber_shadows = slices <= target ? ShadowMethod::kSlices : ShadowMethod::kTraced;
      shadows.reason = Format("self-shadow slices + other yarns as tubes: pilot radiance %.2g from traced (%s)%s", slices,
                              pilot.c_str(), !setup.choose_fiber_shadows ? ", requested"
                                             : slices <= target           ? ", within the target"
                                                                          : ", over the target");
      if (plan->fiber_shadows != ShadowMethod::kTraced) shadows.estimated_error = slices;
      if (setup.ambient > 0) {
        const double texture = error_of(ShadowMethod::kTraced, OcclusionMethod::kTexture);
        const double distance = error_of(ShadowMethod::kTraced, OcclusionMethod::kDistance);
        const OcclusionMethod best = distance <= texture ? OcclusionMethod::kDistance : OcclusionMethod::kTexture;
        const double best_error = std::min(texture, distance);
        if (setup.choose_fiber_occlusion) plan->fiber_occlusion = best_error <= target ? best : OcclusionMethod::kTraced;
        occlusion.reason = Format("occlusion texture %.2g, distance-based %.2g from traced (pilot radiance, %s)%s", texture,
                                  distance, pilot.c_str(), !setup.choose_fiber_occlusion ? ", requested"
                                                           : best_error <= target         ? ", within the target"
                                                                                          : ", over the target");
        if (plan->fiber_occlusion != OcclusionMethod::kTraced)
          occlusion.estimated_error = plan->fiber_occlusion == OcclusionMethod::kTexture ? texture : distance;
      } else {
        if (setup.choose_fiber_occlusion) plan->fiber_occlusion = OcclusionMethod::kTraced;
        occlusion.reason = "no ambient light";
      }
    }
    shadows.chosen = yarn::ToString(plan->fiber_shadows);
    occlusion.chosen = yarn::ToString(plan->fiber_occlusion);
  }
  for (FidelityChoice* c : {&shadows, &occlusion}) {
    out->estimated_error += c->estimated_error;
    out->choices.push_back(*c);
  }
}

}  // namespace

const models::PreparedMaterial* CachedVariants::WithSettings(const Setting& reflection, const Setting& layer) {
  v1::Material variant = base_;
  if (!reflection.param.empty()) variant = models::WithParam(variant, false, reflection.param, reflection.value);
  if (!layer.param.empty()) variant = models::WithParam(variant, true, layer.param, layer.value);
  return Get(variant);
}

const models::PreparedMaterial* CachedVariants::Get(const v1::Material& material) {
  std::shared_ptr<const models::PreparedMaterial> entry;
  if (!cache_.Get(material, registry_, &entry).empty()) return nullptr;
  kept_.push_back(entry);
  return entry.get();
}

std::string FoldEnvironment(const RenderSetup& setup, const std::vector<FoldedEnvironment::Material>& materials,
                            FoldCache* cache, double error_target, bool requested, int threads,
                            const std::function<bool()>& stop, const std::function<bool(uint64_t)>& admit,
                            bool* refused, std::shared_ptr<const FoldedEnvironment>* out,
                            std::vector<FidelityChoice>* choices) {
  *refused = false;
  out->reset();
  const std::string key = FoldCache::Key(setup, materials);
  std::shared_ptr<const FoldedEnvironment> folded = cache ? cache->Find(key) : nullptr;
  const bool kept = folded != nullptr;
  if (!folded) {
    if (std::string e = FoldedEnvironment::Build(setup, materials, threads, stop, admit, refused, &folded); !e.empty())
      return e;
    if (cache) cache->Insert(key, folded, setup);
  }
  std::vector<double> errors;  // the pilot's hits depend on the image size beyond the key
  const std::string pilot = std::to_string(setup.width) + "x" + std::to_string(setup.height);
  if (cache) cache->FindErrors(key, pilot, &errors);
  std::vector<bool> keep;
  if (!ChooseFoldedEnvironment(setup, *folded, materials, error_target, requested, threads, stop, &errors, choices, &keep))
    return "stopped while estimating the fold's error";
  if (cache) cache->KeepErrors(key, pilot, errors);
  if (std::find(keep.begin(), keep.end(), true) != keep.end()) *out = folded->Keeping(keep);
  for (FidelityChoice& c : *choices)
    if (kept && c.chosen == "folded") c.reason += "; the fold kept from an earlier call";
  return "";
}

int EvaluatorIndex(std::vector<Evaluator>* evaluators, const Evaluator& e) {
  for (size_t i = 0; i < evaluators->size(); ++i) {
    const Evaluator& x = (*evaluators)[i];
    if (x.material == e.material && x.with_uv == e.with_uv && x.transmission == e.transmission &&
        x.fiber_axis == e.fiber_axis && x.quantity == e.quantity && x.table == e.table)
      return static_cast<int>(i);
  }
  evaluators->push_back(e);
  return static_cast<int>(evaluators->size() - 1);
}

std::string ChooseFidelity(const RenderSetup& setup, const MaterialInfo& m, MaterialVariants& variants,
                           double target, bool force_full, FidelityPlan* plan, int threads) {
  const std::vector<ObjectMaterial> materials(setup.scene.objects.size(), ObjectMaterial{m, &variants});
  return ChooseFidelity(setup, materials, target, force_full, plan, threads);
}

std::string ChooseFidelity(const RenderSetup& setup, const std::vector<ObjectMaterial>& materials, double target,
                           bool force_full, FidelityPlan* plan, int threads) {
  const std::string failed = "cannot pack a variant of the material for the fidelity choice";
  if (materials.size() != setup.scene.objects.size()) return "one material per object is needed";
  const Pilot pilot(setup);

  plan->evaluators.clear();
  plan->objects.clear();
  plan->fidelity.clear();
  for (size_t o = 0; o < setup.scene.objects.size(); ++o) {
    const MaterialInfo& m = materials[o].info;
    MaterialVariants& variants = *materials[o].variants;
    const models::PreparedMaterial* requested = variants.Requested();
    if (!requested) return failed;
    const Knobs knobs{FindKnob(*m.model, ""),
                      requested->transmission ? FindKnob(*requested->transmission->model, "transmission.") : Knob{}};
    const bool varying = m.model->spatially_varying(), transmits = Transmits(m);
    const Config full{varying, knobs.reflection.full, knobs.layer.full, transmits};
    const double segment = 1.0 / (setup.texture_scale * m.model->ThreadsPerRepeat(m.values));  // scene units
    ObjectFidelity out{setup.scene.objects[o].name, m.model->name(), {}, 0, 0};
    if (setup.scene.objects[o].fibers) {
      // Fibers span pixels here: each fiber is shaded by the fiber model about its own axis, plus the ambient
      // term; the geometry's level of detail was chosen from the pixel footprint when it was generated.
      ObjectShading shading;
      shading.evaluator = EvaluatorIndex(&plan->evaluators, {requested, false, false, true});
      if (setup.ambient > 0 && m.model->has_ambient())
        shading.ambient_evaluator =
            EvaluatorIndex(&plan->evaluators, {requested, false, false, true, models::Quantity::kAmbient});
      const RenderSetup::FiberDetail& d = setup.fiber_detail;
      FidelityChoice geometry{"geometry", d.chosen, d.full, 0, d.reason};
      const RenderSetup* chosen_setup = &setup;
      RenderSetup full_detail;
      PilotTotal traced;
      const bool check = setup.full_detail_fibers && !force_full;
      if (check) {
        full_detail = setup;
        full_detail.scene.fibers = setup.full_detail_fibers;
        full_detail.scene.fiber_visibility = setup.full_detail_visibility;
        if (ChooseFiberGeometry(setup, full_detail, plan->evaluators, shading, target, threads, &geometry, &traced)) {
          plan->fiber_full_detail = true;
          chosen_setup = &full_detail;
        }
      }
      out.estimated_error += geometry.estimated_error;
      out.choices.push_back(geometry);
      ChooseFiberVisibility(*chosen_setup, plan->evaluators, shading, target, force_full, threads,
                            check ? &traced : nullptr, plan, &out);
      plan->objects.push_back(shading);
      plan->fidelity.push_back(std::move(out));
      continue;
    }
    const std::vector<ShadingPoint>& points = pilot.points(static_cast<int>(o));
    Config chosen = full;
    FidelityChoice path{"path", varying ? "BTF" : "BRDF", varying ? "BTF" : "BRDF", 0,
                        varying ? "" : "not spatially varying: the BRDF is the model's only path"};
    FidelityChoice accuracy{knobs.reflection.aspect, KnobText(knobs.reflection.full),
                            KnobText(knobs.reflection.full), 0, ""};
    FidelityChoice layer_accuracy{knobs.layer.aspect, KnobText(knobs.layer.full), KnobText(knobs.layer.full), 0, ""};
    FidelityChoice transmission{"transmission", transmits ? "on" : "off", transmits ? "on" : "off", 0,
                                transmits ? "" : "the material does not transmit"};
    std::string common;  // a reason shared by every choice
    double near_footprint = 0;  // > 0: the BTF nearer than this footprint, the BRDF beyond (per pixel)
    if (force_full) {
      common = "force_full_fidelity";
    } else if (points.empty()) {
      common = "not hit by the pilot rays (too small or out of view): full fidelity";
    } else {
      std::vector<double> reference, candidate;
      if (varying) {
        const size_t n = points.size();
        std::vector<double> pixels_per_thread(n);
        for (size_t i = 0; i < n; ++i)
          pixels_per_thread[i] = points[i].footprint > 0 ? segment / points[i].footprint : 1e9;
        out.pixels_per_thread = Median(pixels_per_thread);
        Config brdf = full;
        brdf.btf = false;
        if (!PilotRadiance(points, m, variants, knobs, full, &reference) ||
            !PilotRadiance(points, m, variants, knobs, brdf, &candidate))
          return failed;
        // Per pixel: the BRDF takes the hits farthest in texture (fewest pixels per thread) first, as many as keep
        // the object's error, sum |BRDF - BTF| x the share of the texture a pixel keeps over them / sum |BTF|
        // over all, within the target. A box filter over the pixel keeps at most 1 / (pi r') of a texture of
        // period r' pixels (the sinc's envelope, r' = 1 / r threads per pixel): the part the BRDF misses.
        std::vector<size_t> order(n);
        for (size_t i = 0; i < n; ++i) order[i] = i;
        std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return pixels_per_thread[a] < pixels_per_thread[b]; });
        double total = 0;
        for (double r : reference) total += std::fabs(r);
        size_t far = 0;  // pilot hits the BRDF takes
        double missed = 0;
        for (; far < n; ++far) {
          const size_t i = order[far];
          // Only where a thread is narrower than a pixel: wider ones are texture a pixel shows, whatever the
          // object's total says.
          if (pixels_per_thread[i] > kMaxBrdfPixelsPerThread) break;
          const double add = std::fabs(candidate[i] - reference[i]) * std::min(1.0, pixels_per_thread[i] / std::numbers::pi);
          if (total <= 0 || (missed + add) / total > target) break;
          missed += add;
        }
        path.estimated_error = total > 0 ? missed / total : 0;
        if (far == n) {
          chosen.btf = false;
          path.chosen = "BRDF";
          path.reason = Format("threads span %.3g pixels (median): a pixel averages them, so the BRDF (the BTF's "
                               "mean) is within %.2g of the BTF", out.pixels_per_thread, path.estimated_error);
        } else if (far == 0) {
          path.reason = Format("threads span %.3g pixels (median): the BTF resolves them (the BRDF would differ "
                               "by more than the target where the texture is coarsest)", out.pixels_per_thread);
        } else {
          // The footprint between the last hit the BRDF takes and the first it does not (geometric mean).
          const double r_far = pixels_per_thread[order[far - 1]], r_near = pixels_per_thread[order[far]];
          near_footprint = segment / std::sqrt(r_far * r_near);
          path.chosen = "BTF near, BRDF far";
          path.reason = Format("per pixel: the BRDF where threads span < %.3g pixels (%.0f%% of the pilot's hits, "
                               "within %.2g of the BTF), the BTF nearer", std::sqrt(r_far * r_near),
                               100.0 * double(far) / double(n), path.estimated_error);
        }
      }
      if (!knobs.reflection.name.empty() &&
          !ChooseKnob(points, m, variants, knobs, knobs.reflection, &Config::knob, target, &chosen, &accuracy))
        return failed;
      if (transmits) {
        bool back_lit = false;
        for (const ShadingPoint& p : points) {
          back_lit = back_lit || p.background.x + p.background.y + p.background.z > 0;
          for (const LightSample& l : p.lights) back_lit = back_lit || l.wi.z < 0;
        }
        if (!back_lit) {
          chosen.transmission = false;
          transmission.chosen = "off";
          transmission.reason = "no light reaches the back of the cloth";
        } else {
          Config off = chosen;
          off.transmission = false;
          if (!PilotRadiance(points, m, variants, knobs, chosen, &reference) ||
              !PilotRadiance(points, m, variants, knobs, off, &candidate))
            return failed;
          const double error = RelativeL1(candidate, reference);
          if (error <= target) {
            chosen.transmission = false;
            transmission.chosen = "off";
            transmission.estimated_error = error;
            transmission.reason = Format("light through the cloth adds only %.2g of the radiance", error);
          } else {
            transmission.reason = Format("light through the cloth adds %.2g of the radiance", error);
          }
        }
      }
      // After the transmission: the layer's approximation is measured on the light the render will take.
      if (!knobs.layer.name.empty() && !ChooseKnob(points, m, variants, knobs, knobs.layer, &Config::layer_knob,
                                                   target, &chosen, &layer_accuracy))
        return failed;
    }
    for (FidelityChoice* c : {&path, &accuracy, &transmission, &layer_accuracy}) {
      if (c->aspect.empty()) continue;  // no such knob
      if (c->reason.empty()) c->reason = common;
      out.estimated_error += c->estimated_error;
      out.choices.push_back(*c);
    }
    ObjectShading shading;
    if (!MakeShading(m, variants, knobs, chosen, &plan->evaluators, &shading)) return failed;
    if (near_footprint > 0) {
      Config far = chosen;
      far.btf = false;
      ObjectShading brdf;
      if (!MakeShading(m, variants, knobs, far, &plan->evaluators, &brdf)) return failed;
      shading.near_evaluator = shading.evaluator;
      shading.near_footprint = near_footprint;
      shading.evaluator = brdf.evaluator;
    }
    plan->objects.push_back(shading);
    plan->fidelity.push_back(std::move(out));
  }
  return "";
}

}  // namespace loomlight::render
