// Portable shim: lets the model files compile as OpenCL C and as C++ from one source.
//
// OpenCL: the .cl entry file includes this first. `real` is the arithmetic type of one work-item: float,
// or floatN when LL_WIDTH = N > 1 (each work-item evaluates N queries as explicit vectors: PoCL 3.1's own
// work-item-loop vectorizer gives up on this model, see docs/models.md
// "The microcylinder model"), or double / doubleN with LL_FP64.
// `scalar` is the element type of material data, `mask` the type of a comparison of reals.
// C++: include <cmath>, open a namespace, `typedef double real;` (or float) and include this file and the
// model headers inside it, so one source gives the double reference and the float native baseline.
// No include guards on purpose: a C++ translation unit may include the set once per namespace.
//
// Model code may therefore use on reals only: arithmetic, comparisons combined with && and ||, `?:` with
// a mask condition and real operands (literals through R()), and the functions below.

#ifdef __OPENCL_C_VERSION__
#ifndef LL_WIDTH
#define LL_WIDTH 1
#endif
#define LL_CAT_(a, b) a##b
#define LL_CAT(a, b) LL_CAT_(a, b)
#ifdef LL_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double scalar;
#define LL_LITERAL(x) x
#else
typedef float scalar;
#define LL_LITERAL(x) x##f  // keeps float kernels free of double constants
#endif
#if LL_WIDTH == 1
typedef scalar real;
typedef int mask;
#define LL_LOAD(i, p) ((real)(p)[i])
#define LL_STORE(v, i, p) ((p)[i] = (v))
#define LL_TO_INT(x) ((int)(x))
#define LL_AS_FLOAT(x) as_float(x)
#elif defined(LL_FP64)
typedef LL_CAT(double, LL_WIDTH) real;
typedef LL_CAT(long, LL_WIDTH) mask;  // what comparing doubleN gives
#define LL_LOAD(i, p) LL_CAT(convert_double, LL_WIDTH)(LL_CAT(vload, LL_WIDTH)(i, p))  // inputs are float
#define LL_STORE(v, i, p) LL_CAT(vstore, LL_WIDTH)(v, i, p)
#else
typedef LL_CAT(float, LL_WIDTH) real;
typedef LL_CAT(int, LL_WIDTH) mask;
#define LL_LOAD(i, p) LL_CAT(vload, LL_WIDTH)(i, p)
#define LL_STORE(v, i, p) LL_CAT(vstore, LL_WIDTH)(v, i, p)
#define LL_TO_INT(x) LL_CAT(convert_int, LL_WIDTH)(x)
#define LL_AS_FLOAT(x) LL_CAT(as_float, LL_WIDTH)(x)
#endif
#define R(x) ((real)(LL_LITERAL(x)))
#define LL_GLOBAL __global
// Everything inlined into the kernel: no calls left in the body.
#define LL_INLINE static inline __attribute__((always_inline))
#define LL_FMIN fmin
#define LL_FMAX fmax
#else
#ifndef LL_SHIM_CXX_ONCE
#define LL_SHIM_CXX_ONCE
#define R(x) real(x)
#define LL_GLOBAL
#define LL_INLINE inline
#define LL_FMIN std::fmin
#define LL_FMAX std::fmax
#define LL_TO_INT(x) static_cast<int>(x)
#define LL_AS_FLOAT(i) __builtin_bit_cast(float, i)
#endif
typedef real scalar;
typedef bool mask;
using std::atan2;
using std::exp;
using std::fabs;
using std::floor;
using std::sqrt;
#endif

#define LL_PI R(3.14159265358979323846)
#define LL_INV_SQRT_2PI R(0.39894228040143267794)

// Directions whose |n.w| is below this lie in the tangent plane to within float input precision
// (a unit float vector carries ~6e-8 absolute error), so reflection models treat them as n.w = 0.
#define LL_HORIZON_EPS R(1e-7)

#if !(defined(__OPENCL_C_VERSION__) && defined(LL_FP64))  // double kernels use the exact builtins
// atan2 with no library call and no branch (PoCL's builtin atan2 is an out-of-line call). Octant reduction
// to a = min/max in [0, 1], then atan(a) = pi/4 + atan((a-1)/(a+1)) above tan(pi/8), leaving |z| <= 0.4142 for
// Cephes' atanf polynomial (about 1 ulp in float). z is one division, (mn - mx)/(mn + mx) or mn/mx.
LL_INLINE real ll_atan2_poly(real y, real x) {
  const real ax = fabs(x), ay = fabs(y);
  const real mx = LL_FMAX(ax, ay), mn = LL_FMIN(ax, ay);
  const mask big = mn > R(0.41421356) * mx;
  const real q = (big ? mn - mx : mn) / (big ? mn + mx : mx);  // NaN for x = y = 0, selected out below
  const real z = mx > R(0.0) ? q : R(0.0);
  const real s = z * z;
  const real p = ((R(8.05374449538e-2) * s - R(1.38776856032e-1)) * s + R(1.99777106478e-1)) * s - R(3.33329491539e-1);
  real r = z + z * s * p + (big ? R(0.78539816) : R(0.0));
  r = ay > ax ? R(1.57079633) - r : r;
  r = x < R(0.0) ? R(3.14159265) - r : r;
  return y < R(0.0) ? -r : r;
}

// exp with no table and no branch: PoCL's builtin expf reads a table of float2 pairs, whose extractelement
// stops its work-item loop vectorizer ("instruction return type cannot be vectorized") and costs a gather.
// Cody-Waite reduction x = n ln2 + r (|r| <= ln2/2, n rounded with the 1.5 * 2^23 trick) and Cephes'
// expf polynomial (about 1 ulp); 2^n is built in the exponent bits. Flushes to 0 below -87 (no denormals).
LL_INLINE real ll_exp_poly(real x) {
  const real xc = LL_FMAX(x, R(-87.0));
  const real n = (xc * R(1.44269504089) + R(12582912.0)) - R(12582912.0);
  const real r = (xc - n * R(0.693359375)) + n * R(2.12194440e-4);
  const real p = ((((R(1.9875691500e-4) * r + R(1.3981999507e-3)) * r + R(8.3334519073e-3)) * r + R(4.1665795894e-2)) * r +
                  R(1.6666665459e-1)) * r + R(5.0000001201e-1);
  const real e = (p * r * r + r) + R(1.0);
  const real scale = LL_AS_FLOAT((LL_TO_INT(n) + 127) << 23);
  return x < R(-87.0) ? R(0.0) : e * scale;
}

#endif

#if defined(__OPENCL_C_VERSION__)
#ifdef LL_FP64
#define ll_atan2 atan2
#define ll_exp exp
#else
#define ll_atan2 ll_atan2_poly
#define ll_exp ll_exp_poly
#endif
#else
inline float ll_atan2(float y, float x) { return ll_atan2_poly(y, x); }  // real is float here
inline double ll_atan2(double y, double x) { return std::atan2(y, x); }
inline float ll_exp(float x) { return ll_exp_poly(x); }
inline double ll_exp(double x) { return std::exp(x); }
#endif

// table[index] per lane, index a real holding a whole number (a per-lane lookup: spatially varying models
// find each query's texture cell). OpenCL C has no gather for vectors, so wide kernels spill the indices
// to private memory and load lane by lane; the arithmetic around it stays vectorised.
#if defined(__OPENCL_C_VERSION__) && LL_WIDTH > 1
LL_INLINE real ll_gather(LL_GLOBAL const scalar* table, real index) {
  scalar lane[LL_WIDTH];
  LL_CAT(vstore, LL_WIDTH)(index, 0, lane);
  for (int i = 0; i < LL_WIDTH; ++i) lane[i] = table[(int)lane[i]];
  return LL_CAT(vload, LL_WIDTH)(0, lane);
}
#else
LL_INLINE real ll_gather(LL_GLOBAL const scalar* table, real index) { return table[(int)index]; }
#endif

// Scales (x, y, z) to unit length: the API accepts directions within its unit tolerance, and the models'
// projections assume exactly unit vectors.
LL_INLINE void ll_normalize(real* x, real* y, real* z) {
  const real inv = R(1.0) / sqrt(*x * *x + *y * *y + *z * *z);
  *x *= inv;
  *y *= inv;
  *z *= inv;
}

// Unit-area Gaussian g(w, x) = exp(-x^2 / (2 w^2)) / (w sqrt(2 pi)), given inv_w = 1 / w; t = x / w first
// (SPEC.md section 1), as a product so that loops over x pay no division.
LL_INLINE real ll_gaussian(real inv_w, real x) {
  const real t = x * inv_w;
  return ll_exp(R(-0.5) * t * t) * (LL_INV_SQRT_2PI * inv_w);
}

// Unit-height Gaussian u(x) = exp(-x^2 / (2 sigma^2)), given inv2s2 = 1 / (2 sigma^2).
LL_INLINE real ll_unit_gaussian(real inv2s2, real x) { return ll_exp(-x * x * inv2s2); }

// Unpolarised dielectric Fresnel reflectance from outside into relative index eta, incidence cosine c in [0,1].
// Returns 1 on total internal reflection. Written with g = eta cos(theta_t) = sqrt(eta^2 - 1 + c^2): one sqrt
// and no trigonometry, rs = (c - g) / (c + g), rp = (eta^2 c - g) / (eta^2 c + g).
LL_INLINE real ll_fresnel_dielectric(scalar eta, real c) {
  const real eta2 = eta * eta;
  const real g2 = eta2 - R(1.0) + c * c;
  const real g = sqrt(LL_FMAX(g2, R(0.0)));
  const real rs = (c - g) / (c + g);
  const real rp = (eta2 * c - g) / (eta2 * c + g);
  const real fr = R(0.5) * (rs * rs + rp * rp);
  return g2 <= R(0.0) ? R(1.0) : fr;
}

// expm1(x) = exp(x) - 1, accurate to a few ulp also for small |x|, where exp(x) - 1 cancels (it returns 0 in
// float for |x| < 3e-8). Float path without library calls (keeps PoCL's vectorizer): the Taylor polynomial
// through x^8/8! on |x| <= 1/2 (truncation < 1.4e-8 relative), ll_exp_poly(x) - 1 outside it (cancellation
// there costs at most a factor 1.6). Same domain as ll_exp_poly (x <= 88).
#if !(defined(__OPENCL_C_VERSION__) && defined(LL_FP64))
LL_INLINE real ll_expm1_poly(real x) {
  const real p = R(1.0) + x * (R(0.5) + x * (R(1.6666666666666667e-1) + x * (R(4.1666666666666667e-2) +
                 x * (R(8.3333333333333333e-3) + x * (R(1.3888888888888889e-3) + x * (R(1.9841269841269841e-4) +
                 x * R(2.4801587301587302e-5)))))));
  return fabs(x) <= R(0.5) ? x * p : ll_exp_poly(x) - R(1.0);
}
#endif
#if defined(__OPENCL_C_VERSION__)
#ifdef LL_FP64
#define ll_expm1 expm1
#else
#define ll_expm1 ll_expm1_poly
#endif
#else
inline float ll_expm1(float x) { return ll_expm1_poly(x); }
inline double ll_expm1(double x) { return std::expm1(x); }
using std::fma;
#endif

// a b - c d to about 1.5 ulp even where the two products nearly cancel (Kahan: the rounding error of c d,
// recovered exactly by an fma, is added back); a plain a b - c d loses all digits there. fma is one
// instruction on CPUs with FMA (PoCL vectorises it); elsewhere a slower exact library routine.
LL_INLINE real ll_diff_of_products(real a, real b, real c, real d) {
  const real cd = c * d;
  const real cd_error = fma(-c, d, cd);
  return fma(a, b, -cd) + cd_error;
}
