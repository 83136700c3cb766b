// Host builds of the shared model source in kernels/models: the double reference (reference.cpp, strict
// IEEE) and the float native baseline (native.cpp, -O3 -march=native, all cores).
#pragma once

#include <cstddef>

namespace loomlight::reference {
// Tangent offset (degrees) at arc length s of a piecewise-linear tangent curve (mc_curve_offset).
double MicrocylinderCurveOffset(const double* offsets, const double* lengths, int n, double s);
int MicrocylinderMaterialStride(int tangent_samples);
void MicrocylinderEval(const double* material, int tangent_samples, const float* wi, const float* wo,
                       size_t n, double* f);
// Woven cotton (kernels/models/woven.h): WV_MATERIAL_SIZE values, then the cell table. With uv (pairs) the
// BTF, with uv = nullptr the BRDF.
int WovenMaterialSize();
void WovenEval(const double* material, const float* wi, const float* wo, const float* uv, size_t n, double* f);
// Thin semi-transparent layer (kernels/models/thin_layer.h): f and the direct transmittance exp(-tau/|n.wo|).
// scattering: TL_SCATTERING_SINGLE or _ALL (the launch-uniform value).
void ThinLayerEval(const double* material, int scattering, const float* wi, const float* wo, size_t n, double* f);
void ThinLayerTransmittance(const double* material, const float* wo, size_t n, double* t);
// Fiber scattering (kernels/models/fiber.h); mode is the launch-uniform value. The ambient factor of Eq. 7
// (RGB per wo) from the packed tables.
void FiberEval(const double* material, int mode, const float* wi, const float* wo, size_t n, double* f);
void FiberAmbient(const double* material, const float* wo, size_t n, double* a);
}  // namespace loomlight::reference

namespace loomlight::native {
// Splits the n queries over all hardware threads.
void MicrocylinderEval(const float* material, int tangent_samples, const float* wi, const float* wo, size_t n,
                       float* f);
void WovenEval(const float* material, const float* wi, const float* wo, const float* uv, size_t n, float* f);
void ThinLayerEval(const float* material, int scattering, const float* wi, const float* wo, size_t n, float* f);
void FiberEval(const float* material, int mode, const float* wi, const float* wo, size_t n, float* f);
}  // namespace loomlight::native
