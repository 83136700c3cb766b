// The double-precision reference: the shared model source compiled as C++ with real = double.
#include <algorithm>
#include <cmath>

#include "server/models/host_models.h"

namespace loomlight::reference {
namespace device {
typedef double real;
#include "common/shim.h"
#include "models/microcylinder.h"
#include "common/ellipse_window.h"
#include "models/woven.h"
#include "models/thin_layer.h"
#include "models/fiber.h"
#include "server/models/host_queries.h"
}  // namespace device

double MicrocylinderCurveOffset(const double* offsets, const double* lengths, int n, double s) {
  return device::mc_curve_offset(offsets, lengths, n, s);
}

int MicrocylinderMaterialStride(int tangent_samples) { return device::mc_material_stride(tangent_samples); }

void MicrocylinderEval(const double* material, int tangent_samples, const float* wi, const float* wo,
                       size_t n, double* f) {
  device::mc_queries(material, tangent_samples, wi, wo, 0, n, f);
}
int WovenMaterialSize() { return WV_MATERIAL_SIZE; }

void WovenEval(const double* material, const float* wi, const float* wo, const float* uv, size_t n, double* f) {
  device::wv_queries(material, wi, wo, uv, 0, n, f);
}

void ThinLayerEval(const double* material, int scattering, const float* wi, const float* wo, size_t n, double* f) {
  device::tl_queries(material, scattering, wi, wo, 0, n, f);
}
void ThinLayerTransmittance(const double* material, const float* wo, size_t n, double* t) {
  for (size_t q = 0; q < n; ++q) t[q] = device::tl_transmittance(material, wo[3 * q], wo[3 * q + 1], wo[3 * q + 2]);
}
void FiberEval(const double* material, int mode, const float* wi, const float* wo, size_t n, double* f) {
  device::fb_queries(material, mode, wi, wo, 0, n, f);
}
void FiberAmbient(const double* material, const float* wo, size_t n, double* a) {
  for (size_t q = 0; q < n; ++q) device::fb_ambient(material, wo[3 * q], wo[3 * q + 1], wo[3 * q + 2], a + 3 * q);
}
}  // namespace loomlight::reference
