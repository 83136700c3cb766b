// `loomlight scenes`: the server's render scenes (ListScenes), readable.
#include <iostream>
#include <sstream>
#include <string>

#include "client/commands.h"
#include "client/param_schema.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

std::string triple(const google::protobuf::RepeatedField<double>& v) {
  std::ostringstream out;
  out << '(';
  for (int i = 0; i < v.size(); ++i) out << (i ? ", " : "") << v[i];
  return out.str() + ')';
}

void print_scene(std::ostream& out, const v1::SceneInfo& scene) {
  out << "\nscene " << scene.name() << " (render --scene " << scene.name() << "): " << scene.description() << '\n';
  // Only scenes that have a ScenePreset value name one (an absent preset is not SCENE_SPHERE, the enum's 0).
  if (scene.has_preset()) out << "  preset: " << v1::ScenePreset_Name(scene.preset()) << " (RenderRequest.scene)\n";
  out << "  shows: " << (scene.fibers() ? "fibers (needs a fiber model; render --yarn)" : "surfaces")
      << (scene.needs_uv() ? ", a material's pattern" : "") << (scene.shows_transmission() ? ", transmission" : "")
      << '\n';
  const v1::RenderCamera& camera = scene.default_camera();
  out << "  camera: at " << triple(camera.position()) << " looking at " << triple(camera.look_at()) << ", "
      << camera.fov_deg() << " deg field of view; texture scale " << scene.default_texture_scale()
      << " repeats per unit\n";
  std::string lighting = scene.default_environment() ? "the built-in sky" : "";
  for (const v1::RenderLight& light : scene.default_lights())
    lighting += (lighting.empty() ? "" : ", ") +
                (light.type() == v1::RenderLight::TYPE_POINT ? "a point light at " + triple(light.position())
                                                             : "a light toward " + triple(light.direction())) +
                " rgb " + triple(light.rgb());
  out << "  lighting: " << lighting << '\n';
  out << "  objects:";
  for (const std::string& object : scene.objects()) out << " '" << object << "'";
  out << '\n';
  print_parameters(out, scene.params());
}

int run_scenes(const ParsedOptions& options) {
  const v1::ListScenesResponse response = Client(options).list_scenes();
  for (const v1::SceneInfo& scene : response.scenes()) print_scene(std::cout, scene);
  return 0;
}

}  // namespace

const Command& scenes_command() {
  static const Command command = {
      "scenes",
      "",
      "list the render scenes with their parameters, default camera and lighting",
      "A scene's parameters are set with render --scene NAME --scene-param NAME=V (repeatable). Ranges are\n"
      "inclusive; angles are in degrees, lengths in scene units.",
      {},
      run_scenes,
  };
  return command;
}

}  // namespace loomlight::client
