// Portable shim: lets the model files compile as OpenCL C (float, or double with LL_FP64) and as C++.
//
// OpenCL: the .cl entry file includes this first; `real` is float, or double when LL_FP64 is defined.
// C++: include <cmath> and <algorithm>, open a namespace, `typedef double real;` (or float) and include this
// file and the model headers inside it, so one source gives the double reference and the float baseline.
// No include guards on purpose: a C++ translation unit may include the set once per namespace.

#ifdef __OPENCL_C_VERSION__
#ifdef LL_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#define R(x) x
#else
typedef float real;
#define R(x) x##f  // keeps float kernels free of double constants
#endif
#define LL_GLOBAL __global
// Everything inlined into the kernel: a call left in the body stops PoCL's work-item loop vectorizer.
#define LL_INLINE static inline __attribute__((always_inline))
#define LL_FMIN fmin
#define LL_FMAX fmax
// A work-group barrier at the top of a uniform loop makes PoCL put its work-item loop inside each
// iteration, the only place its loop vectorizer can widen it (it vectorizes innermost loops only).
#define LL_UNIFORM_LOOP_BARRIER() barrier(CLK_LOCAL_MEM_FENCE)
#else
#ifndef LL_SHIM_CXX_ONCE
#define LL_SHIM_CXX_ONCE
#define R(x) real(x)
#define LL_GLOBAL
#define LL_INLINE inline
#define LL_FMIN std::fmin
#define LL_FMAX std::fmax
#define LL_UNIFORM_LOOP_BARRIER()
#endif
using std::atan2;
using std::exp;
using std::fabs;
using std::sqrt;
#endif

#define LL_PI R(3.14159265358979323846)
#define LL_INV_SQRT_2PI R(0.39894228040143267794)

// Directions whose |n.w| is below this lie in the tangent plane to within float input precision
// (a unit float vector carries ~6e-8 absolute error), so reflection models treat them as n.w = 0.
#define LL_HORIZON_EPS R(1e-7)

// atan2 with no library call and no branch, so PoCL vectorizes it (its builtin atan2 is a call the
// work-item vectorizer cannot widen). Octant reduction to a in [0, 1], then atan(a) = pi/4 + atan((a-1)/(a+1))
// above tan(pi/8), leaving |z| <= 0.4142 for Cephes' atanf polynomial (about 1 ulp in float).
LL_INLINE float ll_atan2_poly(float y, float x) {
  const float ax = fabs(x), ay = fabs(y);
  const float mx = LL_FMAX(ax, ay), mn = LL_FMIN(ax, ay);
  const float a = mx > 0.0f ? mn / mx : 0.0f;
  const int big = a > 0.41421356f;
  const float z = big ? (a - 1.0f) / (a + 1.0f) : a;
  const float s = z * z;
  const float p = ((8.05374449538e-2f * s - 1.38776856032e-1f) * s + 1.99777106478e-1f) * s - 3.33329491539e-1f;
  float r = z + z * s * p + (big ? 0.78539816f : 0.0f);
  r = ay > ax ? 1.57079633f - r : r;
  r = x < 0.0f ? 3.14159265f - r : r;
  return y < 0.0f ? -r : r;
}
#if defined(__OPENCL_C_VERSION__)
#ifdef LL_FP64
#define ll_atan2 atan2
#else
#define ll_atan2 ll_atan2_poly
#endif
#else
inline float ll_atan2(float y, float x) { return ll_atan2_poly(y, x); }
inline double ll_atan2(double y, double x) { return std::atan2(y, x); }
#endif

// Unit-area Gaussian g(w, x) = exp(-x^2 / (2 w^2)) / (w sqrt(2 pi)); t = x / w first (SPEC.md section 1).
LL_INLINE real ll_gaussian(real w, real x) {
  const real t = x / w;
  return exp(R(-0.5) * t * t) * (LL_INV_SQRT_2PI / w);
}

// Unit-height Gaussian u(x) = exp(-x^2 / (2 sigma^2)), given inv2s2 = 1 / (2 sigma^2).
LL_INLINE real ll_unit_gaussian(real inv2s2, real x) { return exp(-x * x * inv2s2); }

// Unpolarised dielectric Fresnel reflectance from outside into relative index eta, incidence cosine c in [0,1].
// Returns 1 on total internal reflection. Written with sqrt only: no trigonometry in the kernels.
LL_INLINE real ll_fresnel_dielectric(real eta, real c) {
  const real sin2_t = (R(1.0) - c * c) / (eta * eta);
  const real cos_t = sqrt(LL_FMAX(R(1.0) - sin2_t, R(0.0)));
  const real rs = (c - eta * cos_t) / (c + eta * cos_t);
  const real rp = (eta * c - cos_t) / (eta * c + cos_t);
  const real fr = R(0.5) * (rs * rs + rp * rp);
  return sin2_t >= R(1.0) ? R(1.0) : fr;
}
