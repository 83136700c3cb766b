// Studio lighting (docs/thumbnails.md "Lighting presets"): rectangular area lights (softboxes) and the presets a
// product photographer uses, key, fill and rim softboxes placed around the subject relative to the camera,
// with the studio map (Environment::Studio).
#pragma once

#include <span>
#include <string_view>
#include <vector>

#include "server/render/scene.h"

namespace loomlight::render {

// A softbox centred at `centre`, its emitting side facing `facing` (normalised here, must not be zero), `width`
// along its u axis and `height` along `up` made perpendicular to `facing`; an `up` that is zero or parallel to
// `facing` gives way to +y, then +z (RenderLight's default: +y, or +z when it faces straight up or down).
Light RectLight(Vec3 centre, Vec3 facing, double width, double height, Vec3 up, Rgb radiance);

// One light sample of a rect light seen from `point`: the direction toward a point of the rectangle, the
// distance to it and its radiance over the sample's density per steradian, so that the irradiance at a
// receiver is the mean of incident x its cosine there. Large or close softboxes are sampled uniformly in the
// solid angle they subtend (Urena et al. 2013, "An Area-Preserving Parametrization for Spherical Rectangles"):
// only the receiver's cosine varies between samples; small ones (below kMinSphericalRectSolidAngle, where the
// parametrization loses precision and gains nothing) uniformly by area.
constexpr double kMinSphericalRectSolidAngle = 1e-4;  // steradians
struct RectLightSample {
  Vec3 direction;
  double distance = 0;
  Rgb incident;
};
// (u0, u1) uniform in [0, 1). False, and nothing is added, when the point is behind the light or in its plane
// (it emits from its front only) or the light has no area.
bool SampleRectLight(const Light& light, Vec3 point, double u0, double u1, RectLightSample* out);

// A preset's light in a frame of the subject's bounding sphere and the camera: its direction from the sphere's
// centre by azimuth (from the camera's side, positive toward the camera's right, 180 behind the subject) and
// elevation (above the plane through the centre perpendicular to the camera's up), the softbox facing the centre.
struct PresetLight {
  std::string_view role;       // "key", "fill", "rim", "top"
  double azimuth_deg = 0, elevation_deg = 0;
  double distance = 4;         // centre to centre, in subject radii
  double width = 2, height = 2;  // in subject radii (height along the camera's up where it can be)
  Rgb radiance;                // the same at every scale: a softbox's solid angle does not change with the subject's size
};

struct LightingPreset {
  std::string_view name, description;
  std::vector<PresetLight> lights;
  double environment_intensity = 0;  // the studio map's radiance scale; 0: no environment
};

// Every preset, "studio" first (RenderRequest.lighting, ListScenesResponse.lighting_presets).
std::span<const LightingPreset> LightingPresets();
// The preset of that name, or null.
const LightingPreset* FindLightingPreset(std::string_view name);

// The preset's softboxes placed around the sphere (centre, radius > 0) as seen by `camera`.
std::vector<Light> PlaceLights(const LightingPreset& preset, Vec3 centre, double radius, const CameraSpec& camera);

// The sphere around a scene's objects (their shapes' bounding box, fibers' and a mesh's bounds) that presets are
// placed around; a scene with nothing to bound: a sphere at the camera's look-at point, a quarter of its distance.
void SubjectSphere(const Scene& scene, const CameraSpec& camera, Vec3* centre, double* radius);

}  // namespace loomlight::render
