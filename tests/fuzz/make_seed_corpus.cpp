// Writes the request fuzzer's seed corpus (tests/fuzz/corpus/fuzz_request/seed_*): small valid requests of every
// RPC and every model the registry has (found there, not named here), each option the checks branch on, and a few
// requests that must be refused; and, with a second directory, the WIF fuzzer's structure-aware seeds
// (tests/fuzz/corpus/fuzz_wif/seed_*): drafts up to the 1 MiB field limit that repeat indices and fill every
// count, the shapes that once multiplied a parse's memory (issue 44), and every colour count filled (issue 47).
// Run it again when models or request fields are added:
//
//     build/tests/fuzz/make_seed_corpus tests/fuzz/corpus/fuzz_request tests/fuzz/corpus/fuzz_wif
//
// The WIF corpus's other inputs are hand-written drafts.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include "loomlight/v1/loomlight.pb.h"
#include "server/models/registry.h"

namespace loomlight {
namespace {

enum RpcByte : char { kEvaluate = 0, kSample = 1, kTabulate = 2, kRender = 3, kNoFp64 = 4, kCreateBtf = 8,
                      kFitMaterial = 16 };

std::filesystem::path out_dir;
int written = 0;

void Write(const std::string& name, char rpc, const google::protobuf::Message& request) {
  std::string bytes(1, rpc);
  request.AppendToString(&bytes);
  std::ofstream(out_dir / ("seed_" + name), std::ios::binary) << bytes;
  ++written;
}

// Two queries: a mirror-like pair above the surface, and one through the cloth (transmission, the back side).
void AddPairs(google::protobuf::RepeatedField<float>* wi, google::protobuf::RepeatedField<float>* wo) {
  for (float v : {0.0f, 0.6f, 0.8f, 0.0f, 0.0f, -1.0f}) wi->Add(v);
  for (float v : {0.0f, -0.6f, 0.8f, 0.6f, 0.0f, 0.8f}) wo->Add(v);
}

v1::Material Preset(const std::string& name) {
  v1::Material m;
  m.set_preset(name);
  return m;
}

// The model spelled out parameter by parameter (its defaults), with its text parameters left out.
v1::Material Spelled(const models::Model& model) {
  v1::Material m;
  m.set_model(model.name());
  for (const auto& [name, values] : model.DefaultValues()) {
    v1::Param* p = m.add_params();
    p->set_name(name);
    p->mutable_values()->Add(values.begin(), values.end());
  }
  return m;
}

const char kTwillWif[] =
    "[WIF]\nVersion=1.1\n[CONTENTS]\nWEAVING=yes\nTHREADING=yes\nTIEUP=yes\nTREADLING=yes\n[WEAVING]\nShafts=4\n"
    "Treadles=4\n[THREADING]\n1=1\n2=2\n3=3\n4=4\n[TIEUP]\n1=1,2\n2=2,3\n3=3,4\n4=4,1\n[TREADLING]\n1=1\n2=2\n3=3\n4=4\n";

// ---- WIF drafts at scale ----

// A treadled draft on `shafts` shafts and `treadles` treadles, every warp end threaded in turn, tie-up row t
// listing `tieup` and each of `picks` picks pressing `pressed`.
std::string TreadledDraft(int shafts, int treadles, int picks, const std::string& tieup, const std::string& pressed) {
  std::string text = "[WIF]\nVersion=1.1\n[CONTENTS]\nWEAVING=yes\nTHREADING=yes\nTIEUP=yes\nTREADLING=yes\n"
                     "[WEAVING]\nShafts=" + std::to_string(shafts) + "\nTreadles=" + std::to_string(treadles) +
                     "\n[THREADING]\n";
  for (int w = 1; w <= 256; ++w) text += std::to_string(w) + "=" + std::to_string(1 + (w - 1) % shafts) + "\n";
  text += "[TIEUP]\n";
  for (int t = 1; t <= treadles; ++t) text += std::to_string(t) + "=" + tieup + "\n";
  text += "[TREADLING]\n";
  for (int p = 1; p <= picks; ++p) text += std::to_string(p) + "=" + pressed + "\n";
  return text;
}

// `item` n times, comma-separated; or 1..n when item is empty.
std::string List(const std::string& item, int n) {
  std::string s;
  for (int i = 1; i <= n; ++i) {
    if (i > 1) s += ',';
    s += item.empty() ? std::to_string(i) : item;
  }
  return s;
}

// The drafts a WIF parse must stay linear on: each under the 1 MiB limit.
std::vector<std::pair<std::string, std::string>> WifDraftsAtScale() {
  std::string liftplan = "[WIF]\nVersion=1.1\n[CONTENTS]\nWEAVING=yes\nTHREADING=yes\nLIFTPLAN=yes\n[WEAVING]\n"
                         "Shafts=2\n[THREADING]\n1=1\n2=2\n[LIFTPLAN]\n";
  for (int p = 1; p <= 256; ++p) liftplan += std::to_string(p) + "=" + List("2", 1500) + "\n";
  std::string sections = TreadledDraft(4, 4, 4, "1,2", "1");
  for (int i = 0; sections.size() < 900000; ++i) sections += "[PRIVATE" + std::to_string(i) + "]\nfree text\n";
  // Every count of the colour sections filled (issue 47): 256 colours, each of 256 warp threads and picks coloured.
  std::string colors = TreadledDraft(4, 4, 256, "1,2", "1");
  colors += "[COLOR PALETTE]\nEntries=256\nForm=RGB\nRange=0,65535\n[COLOR TABLE]\n";
  for (int i = 1; i <= 256; ++i) colors += std::to_string(i) + "=" + std::to_string(i * 255) + ",0,65535\n";
  for (const char* section : {"[WARP COLORS]\n", "[WEFT COLORS]\n"}) {
    colors += section;
    for (int i = 1; i <= 256; ++i) colors += std::to_string(i) + "=" + std::to_string(257 - i) + "\n";
  }
  // A colour with its values repeated up to the field limit: refused at the fourth.
  const std::string long_color =
      TreadledDraft(4, 4, 4, "1,2", "1") + "[WARP]\nColor=1\n[COLOR TABLE]\n1=" + List("0", 400000);
  return {
      {"repeated_tieup_and_treadling", TreadledDraft(4, 1, 256, List("1", 100000), List("1", 1400))},
      {"repeated_treadling", TreadledDraft(4, 4, 256, "1,2", List("3", 1900))},
      {"every_treadle_every_shaft", TreadledDraft(256, 256, 256, List("", 256), List("", 256))},
      {"repeated_liftplan", liftplan},
      {"section_flood", sections},
      {"every_colour", colors},
      {"repeated_colour_values", long_color + "\n"},
  };
}

void WriteWifSeeds(const std::filesystem::path& dir) {
  std::filesystem::create_directories(dir);
  for (const auto& [name, text] : WifDraftsAtScale()) {
    std::ofstream(dir / ("seed_" + name + ".wif"), std::ios::binary) << text;
    ++written;
  }
}

void WriteEvaluateSeeds(const models::Registry& registry) {
  const models::Model* surface = nullptr;      // a reflection model, for a curtain's front
  const models::Model* transmitting = nullptr;  // a layer for the curtain
  for (const auto& model : registry.models()) {
    const std::string& first = model->presets().front().name;
    for (const models::PresetSpec& preset : model->presets()) {
      v1::EvaluateRequest r;
      *r.mutable_material() = Preset(preset.name);
      AddPairs(r.mutable_wi(), r.mutable_wo());
      Write("evaluate_" + preset.name, kEvaluate, r);
    }
    v1::EvaluateRequest spelled;
    *spelled.mutable_material() = Spelled(*model);
    AddPairs(spelled.mutable_wi(), spelled.mutable_wo());
    spelled.set_precision(v1::PRECISION_FP64);
    if (!model->accuracy_knob().param.empty()) spelled.set_error_target(0.05);
    Write("evaluate_" + model->name() + "_params_fp64", kEvaluate, spelled);
    if (model->spatially_varying()) {
      v1::EvaluateRequest r;
      *r.mutable_material() = Preset(first);
      AddPairs(r.mutable_wi(), r.mutable_wo());
      for (float v : {0.25f, 0.5f, -3.0f, 7.5f}) r.add_uv(v);
      Write("evaluate_" + first + "_uv", kEvaluate, r);
    }
    if (model->has_ambient()) {
      v1::EvaluateRequest r;
      *r.mutable_material() = Preset(first);
      for (float v : {0.0f, 0.0f, 1.0f}) r.add_wo(v);
      r.set_quantity(v1::QUANTITY_AMBIENT);
      Write("evaluate_" + first + "_ambient", kEvaluate, r);
    }
    if (!model->fiber_axis_param().empty()) {
      v1::EvaluateRequest r;
      *r.mutable_material() = Preset(first);
      AddPairs(r.mutable_wi(), r.mutable_wo());
      for (float v : {1.0f, 0.0f, 0.0f, 0.0f, 0.6f, 0.8f}) r.add_fiber_axis(v);
      Write("evaluate_" + first + "_fiber_axis", kEvaluate, r);
    }
    for (const models::ParamSpec& p : model->params())
      if (p.type == models::ParamType::kText) {
        v1::EvaluateRequest r;
        *r.mutable_material() = Preset(first);
        v1::Param* text = r.mutable_material()->add_params();
        text->set_name(p.name);
        text->set_text(kTwillWif);
        AddPairs(r.mutable_wi(), r.mutable_wo());
        Write("evaluate_" + first + "_text_" + p.name, kEvaluate, r);
        if (p.name.size() > 4 && p.name.compare(p.name.size() - 4, 4, ".wif") == 0) {
          text->set_text(WifDraftsAtScale().front().second);  // repeats up to the field limit: refused, cheaply
          Write("evaluate_" + first + "_text_" + p.name + "_repeats", kEvaluate, r);
        }
      }
    if (model->transmission()) transmitting = model.get();
    else if (model->fiber_axis_param().empty()) surface = model.get();
  }
  v1::EvaluateRequest curtain;
  *curtain.mutable_material() = Preset(surface->presets().front().name);
  *curtain.mutable_material()->mutable_transmission() = Preset(transmitting->presets().front().name);
  AddPairs(curtain.mutable_wi(), curtain.mutable_wo());
  Write("evaluate_curtain", kEvaluate, curtain);
  // Refusals: a direction that is not unit, an unknown preset, fp64 on a device without it.
  v1::EvaluateRequest bad = curtain;
  bad.set_wo(0, 2.0f);
  Write("evaluate_refused_direction", kEvaluate, bad);
  bad = curtain;
  bad.mutable_material()->set_preset("no such preset");
  Write("evaluate_refused_preset", kEvaluate, bad);
  bad = curtain;
  bad.set_precision(v1::PRECISION_FP64);
  Write("evaluate_refused_fp64", kEvaluate | kNoFp64, bad);
}

void WriteSampleSeeds(const models::Registry& registry) {
  for (const auto& model : registry.models()) {
    v1::SampleRequest r;
    *r.mutable_material() = Preset(model->presets().front().name);
    for (float v : {0.0f, 0.6f, 0.8f}) r.add_wo(v);
    if (model->spatially_varying()) r.add_uv(0.5f), r.add_uv(0.25f);
    r.set_seed(1);
    Write("sample_" + model->name(), kSample, r);
  }
  v1::SampleRequest r;
  *r.mutable_material() = Preset(registry.models().front()->presets().front().name);
  for (float v : {0.0f, 0.6f, 0.8f, 0.0f, 0.0f, 1.0f}) r.add_wo(v);
  for (float v : {0.1f, 0.5f, 0.9f, 0.0f, 0.25f, 0.999f}) r.add_random(v);
  Write("sample_random", kSample, r);
}

void WriteTabulateSeeds(const models::Registry& registry) {
  const std::string preset = registry.models().front()->presets().front().name;
  v1::TabulateRequest r;
  *r.mutable_material() = Preset(preset);
  r.mutable_in_plane()->add_theta_i_deg(30);
  r.mutable_in_plane()->add_theta_i_deg(-60);
  r.mutable_in_plane()->set_theta_o_count(9);
  r.mutable_in_plane()->set_full_circle(true);
  r.set_format(v1::TABLE_FORMAT_CSV);
  Write("tabulate_in_plane_csv", kTabulate, r);
  r.mutable_anisotropic()->set_theta_i_count(2);
  r.mutable_anisotropic()->set_phi_i_count(3);
  r.mutable_anisotropic()->set_theta_o_count(4);
  r.mutable_anisotropic()->set_phi_o_count(5);
  r.set_format(v1::TABLE_FORMAT_EXR);
  r.set_precision(v1::PRECISION_FP64);
  Write("tabulate_anisotropic_exr", kTabulate, r);
  r.mutable_merl()->set_phi_h_samples(2);
  r.set_format(v1::TABLE_FORMAT_MERL);
  Write("tabulate_merl", kTabulate, r);
}

void WriteRenderSeeds(const models::Registry& registry) {
  const models::Model* fiber = nullptr;
  const models::Model* patterned = nullptr;  // a model with a weave pattern, for the woven patch's layout
  for (const auto& model : registry.models()) {
    if (!model->fiber_axis_param().empty()) fiber = model.get();
    models::weave::WeavePattern pattern;
    if (model->WeavePatternOf(model->DefaultValues(), &pattern).empty()) patterned = model.get();
  }
  v1::RenderRequest r;
  *r.mutable_material() = Preset(registry.models().front()->presets().front().name);
  r.set_width(8);
  r.set_height(6);
  r.set_samples_per_pixel(1);
  Write("render_sphere", kRender, r);
  r.set_scene(v1::SCENE_CURTAIN);
  r.set_format(v1::RENDER_FORMAT_EXR);
  v1::RenderLight* light = r.add_lights();
  light->set_type(v1::RenderLight::TYPE_POINT);
  for (double v : {1.0, 2.0, 3.0}) light->add_position(v), light->add_rgb(v);
  for (double v : {0.0, 0.0, 4.0}) r.mutable_camera()->add_position(v);
  for (double v : {0.0, 0.0, 0.0}) r.mutable_camera()->add_look_at(v);
  r.mutable_camera()->set_fov_deg(40);
  Write("render_curtain_lights_camera", kRender, r);
  r.clear_lights();
  r.mutable_environment()->set_name("studio");
  r.mutable_environment()->set_intensity(2);
  r.set_scene(v1::SCENE_CYLINDERS);
  Write("render_cylinders_environment", kRender, r);
  v1::RenderRequest yarn;
  *yarn.mutable_material() = Preset(fiber->presets().front().name);
  yarn.set_scene(v1::SCENE_YARN);
  yarn.set_width(8);
  yarn.set_height(8);
  yarn.set_samples_per_pixel(1);
  yarn.set_fiber_detail(v1::FIBER_DETAIL_CORES);
  Write("render_yarn", kRender, yarn);
  yarn.set_scene(v1::SCENE_WOVEN_PATCH);
  *yarn.mutable_woven()->mutable_weave() = Preset(patterned->presets().front().name);
  yarn.mutable_woven()->set_repeats_u(1);
  yarn.mutable_woven()->set_repeats_v(1);
  Write("render_woven_patch", kRender, yarn);
  yarn.clear_woven();
  yarn.clear_scene();  // named by scene_name alone, as scenes without a ScenePreset value are
  yarn.set_scene_name("knit_patch");
  yarn.mutable_knit()->set_stitch(v1::KNIT_RIB_1X1);
  yarn.mutable_knit()->set_wales(2);
  yarn.mutable_knit()->set_courses(2);
  Write("render_knit_patch", kRender, yarn);
  yarn.clear_knit();
  yarn.set_scene_name("yarn_curves");
  v1::YarnCentreCurve* curve = yarn.mutable_curves()->add_yarns();
  for (double v : {0.0, 0.0, 0.0, 0.2, 0.0, 0.1, 0.4, 0.1, 0.0, 0.6, 0.0, 0.0}) curve->add_points(v);
  curve->set_bspline(true);
  curve->set_radius(0.02);
  Write("render_yarn_curves", kRender, yarn);
}

// CreateBtf: a woven material on rings, one from fibers on a preset grid, and a name that must be refused.
void WriteCreateBtfSeeds() {
  v1::CreateBtfRequest r;
  r.set_name("twill_8");
  *r.mutable_material() = Preset("cotton_twill");
  r.set_resolution(8);
  for (auto [theta, count] : {std::pair{0.0, 1u}, {30.0, 6u}, {60.0, 8u}}) {
    v1::BtfRing* ring = r.mutable_grid()->add_rings();
    ring->set_theta(theta);
    ring->set_count(count);
  }
  r.mutable_compression()->set_max_components(4);
  r.mutable_compression()->set_target_psnr_db(40);
  Write("create_btf_rings", kCreateBtf, r);
  v1::CreateBtfRequest fibers;
  fibers.set_name("fibers");
  *fibers.mutable_material() = Preset("cotton");
  fibers.mutable_grid()->set_preset("h2");
  fibers.set_resolution(16);
  fibers.mutable_fibers()->mutable_yarn()->set_preset("cotton1");
  *fibers.mutable_fibers()->mutable_woven()->mutable_weave() = Preset("cotton_twill");
  fibers.mutable_fibers()->mutable_woven()->set_crimp(0.5);
  fibers.mutable_fibers()->set_samples_per_texel(2);
  Write("create_btf_fibers", kCreateBtf, fibers);
  fibers.mutable_fibers()->clear_woven();
  fibers.mutable_fibers()->mutable_knit()->set_stitch(v1::KNIT_RIB_1X1);
  Write("create_btf_fibers_knit", kCreateBtf, fibers);
  r.set_name("../escape");
  Write("create_btf_refused_name", kCreateBtf, r);
}

// FitMaterial: a preset to a GLB, to MaterialX, colourways with a panel binding on a stored mesh, a fiber model.
void WriteFitMaterialSeeds() {
  v1::FitMaterialRequest r;
  *r.mutable_material() = Preset("silk_shot");
  r.set_target(v1::FIT_TARGET_GLTF_SHEEN);
  r.set_format(v1::EXPORT_FORMAT_GLB);
  r.set_name("silk");
  Write("fit_gltf_glb", kFitMaterial, r);
  r.set_target(v1::FIT_TARGET_OPENPBR);
  r.set_format(v1::EXPORT_FORMAT_MTLX);
  Write("fit_openpbr_mtlx", kFitMaterial, r);
  v1::FitMaterialRequest ways;
  ways.set_target(v1::FIT_TARGET_GLTF_SHEEN);
  ways.set_format(v1::EXPORT_FORMAT_GLTF);
  ways.mutable_mesh()->set_name("garment");
  for (const char* preset : {"cotton_twill", "velvet"}) {
    v1::Colourway* way = ways.add_colourways();
    way->set_name(preset);
    *way->mutable_material() = Preset(preset);
  }
  v1::MaterialBinding* binding = ways.mutable_colourways(1)->add_bindings();
  binding->set_mesh_material("collar");
  *binding->mutable_material() = Preset("silk_shot");
  Write("fit_colourways_mesh", kFitMaterial, ways);
  r.mutable_material()->Clear();
  r.mutable_material()->set_model("fiber");
  Write("fit_refused_fiber", kFitMaterial, r);
}

}  // namespace
}  // namespace loomlight

int main(int argc, char** argv) {
  if (argc != 2 && argc != 3) {
    std::fprintf(stderr, "usage: %s REQUEST_SEED_DIR [WIF_SEED_DIR]\n", argv[0]);
    return 2;
  }
  loomlight::out_dir = argv[1];
  std::filesystem::create_directories(loomlight::out_dir);
  const loomlight::models::Registry& registry = loomlight::models::Registry::Global();
  loomlight::WriteEvaluateSeeds(registry);
  loomlight::WriteSampleSeeds(registry);
  loomlight::WriteTabulateSeeds(registry);
  loomlight::WriteRenderSeeds(registry);
  loomlight::WriteCreateBtfSeeds();
  loomlight::WriteFitMaterialSeeds();
  if (argc == 3) loomlight::WriteWifSeeds(argv[2]);
  std::printf("%d seeds written to %s\n", loomlight::written, argv[1]);
  return 0;
}
