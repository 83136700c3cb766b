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
}  // namespace device

double MicrocylinderCurveOffset(const double* offsets, const double* lengths, int n, double s) {
  return device::mc_curve_offset(offsets, lengths, n, s);
}

int MicrocylinderMaterialStride(int tangent_samples) { return device::mc_material_stride(tangent_samples); }

void MicrocylinderEval(const double* material, int tangent_samples, const float* wi, const float* wo,
                       size_t n, double* f) {
  for (size_t q = 0; q < n; ++q)
    device::mc_eval(material, tangent_samples, wi[3 * q], wi[3 * q + 1], wi[3 * q + 2], wo[3 * q],
                    wo[3 * q + 1], wo[3 * q + 2], f + 3 * q);
}
int WovenMaterialSize() { return WV_MATERIAL_SIZE; }

void WovenEval(const double* material, const float* wi, const float* wo, const float* uv, size_t n, double* f) {
  for (size_t q = 0; q < n; ++q) {
    const float* a = wi + 3 * q;
    const float* b = wo + 3 * q;
    if (uv)
      device::wv_btf(material, a[0], a[1], a[2], b[0], b[1], b[2], uv[2 * q], uv[2 * q + 1], f + 3 * q);
    else
      device::wv_brdf(material, a[0], a[1], a[2], b[0], b[1], b[2], f + 3 * q);
  }
}

void ThinLayerEval(const double* material, const float* wi, const float* wo, size_t n, double* f) {
  for (size_t q = 0; q < n; ++q) {
    const float* a = wi + 3 * q;
    const float* b = wo + 3 * q;
    device::tl_eval(material, a[0], a[1], a[2], b[0], b[1], b[2], f + 3 * q);
  }
}
void ThinLayerTransmittance(const double* material, const float* wo, size_t n, double* t) {
  for (size_t q = 0; q < n; ++q) t[q] = device::tl_transmittance(material, wo[3 * q], wo[3 * q + 1], wo[3 * q + 2]);
}
void FiberEval(const double* material, int mode, const float* wi, const float* wo, size_t n, double* f) {
  for (size_t q = 0; q < n; ++q) {
    const float* a = wi + 3 * q;
    const float* b = wo + 3 * q;
    device::fb_eval(material, mode, a[0], a[1], a[2], b[0], b[1], b[2], f + 3 * q);
  }
}
void FiberAmbient(const double* material, const float* wo, size_t n, double* a) {
  for (size_t q = 0; q < n; ++q) device::fb_ambient(material, wo[3 * q], wo[3 * q + 1], wo[3 * q + 2], a + 3 * q);
}
}  // namespace loomlight::reference
