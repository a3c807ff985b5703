// casadi_real as a bundle of UVMS_LANES environments, one per SIMD lane (GCC vector
// extension), so that CasADi-generated C compiled as C++ runs every scalar operation of
// the generated code on UVMS_LANES environments at once. The generated code is
// branch-free (the project builds every solve as an SX expression), so lanes never need
// to diverge.
//
// Defines expected from the build: UVMS_REAL (double or float), UVMS_LANES (1, 2, 4, 8,
// 16), and optionally UVMS_SIN / UVMS_COS / UVMS_TAN: glibc's vector maths (libmvec)
// entry points for this width, e.g. _ZGVeN8v_sin for 8 doubles with AVX-512; without
// them sin, cos and tan run lane by lane.
#pragma once
#include <math.h>

typedef UVMS_REAL lane_t;
typedef lane_t lanes_t __attribute__((vector_size(UVMS_LANES * sizeof(lane_t))));

struct vreal {
  lanes_t v;
  vreal() = default;
  vreal(lanes_t x) : v(x) {}
  vreal(double x) : v(lanes_t{} + (lane_t)x) {}
  vreal(float x) : v(lanes_t{} + (lane_t)x) {}
  vreal(int x) : v(lanes_t{} + (lane_t)x) {}
  vreal(long x) : v(lanes_t{} + (lane_t)x) {}
  vreal(long long x) : v(lanes_t{} + (lane_t)x) {}
  vreal& operator+=(const vreal& o) { v += o.v; return *this; }
  vreal& operator-=(const vreal& o) { v -= o.v; return *this; }
  vreal& operator*=(const vreal& o) { v *= o.v; return *this; }
  vreal& operator/=(const vreal& o) { v /= o.v; return *this; }
};

static inline vreal operator+(const vreal& a, const vreal& b) { return vreal(a.v + b.v); }
static inline vreal operator-(const vreal& a, const vreal& b) { return vreal(a.v - b.v); }
static inline vreal operator*(const vreal& a, const vreal& b) { return vreal(a.v * b.v); }
static inline vreal operator/(const vreal& a, const vreal& b) { return vreal(a.v / b.v); }
static inline vreal operator-(const vreal& a) { return vreal(-a.v); }
static inline vreal operator+(const vreal& a) { return a; }

#define UVMS_LANEWISE(name, scalar)                                  \
  static inline vreal name(const vreal& x) {                         \
    vreal r;                                                         \
    for (int i = 0; i < UVMS_LANES; ++i) r.v[i] = scalar(x.v[i]);    \
    return r;                                                        \
  }
// sqrt and fabs vectorize by themselves under -O3 -fno-math-errno.
UVMS_LANEWISE(sqrt, __builtin_sqrt)
UVMS_LANEWISE(fabs, __builtin_fabs)

#if defined(UVMS_SIN) && defined(UVMS_COS) && defined(UVMS_TAN)
extern "C" lanes_t UVMS_SIN(lanes_t);
extern "C" lanes_t UVMS_COS(lanes_t);
extern "C" lanes_t UVMS_TAN(lanes_t);
static inline vreal sin(const vreal& x) { return vreal(UVMS_SIN(x.v)); }
static inline vreal cos(const vreal& x) { return vreal(UVMS_COS(x.v)); }
static inline vreal tan(const vreal& x) { return vreal(UVMS_TAN(x.v)); }
#else
UVMS_LANEWISE(sin, ::sin)
UVMS_LANEWISE(cos, ::cos)
UVMS_LANEWISE(tan, ::tan)
#endif
// asin and atan2 (Euler angles of a rotation matrix) lane by lane: libm's results.
UVMS_LANEWISE(asin, ::asin)
static inline vreal atan2(const vreal& y, const vreal& x) {
  vreal r;
  for (int i = 0; i < UVMS_LANES; ++i) r.v[i] = ::atan2(y.v[i], x.v[i]);
  return r;
}

// Comparisons and logic, lane by lane, as C gives them: 0 or 1 in each lane (no lane
// ever branches; a select in the generated code is arithmetic on these). A GCC vector
// comparison gives an integer mask of the same width (-1 where true), and masking the bit
// pattern of 1.0 with it gives 1.0 or 0.0.
typedef decltype(lanes_t{} < lanes_t{}) uvms_mask_t;
static inline vreal uvms_from_mask(uvms_mask_t m) {
  return vreal((lanes_t)(m & (uvms_mask_t)(lanes_t{} + (lane_t)1)));
}
static inline lanes_t uvms_blend(uvms_mask_t m, lanes_t a, lanes_t b) {  // m ? a : b
  return (lanes_t)((m & (uvms_mask_t)a) | (~m & (uvms_mask_t)b));
}
static inline vreal operator<(const vreal& a, const vreal& b) { return uvms_from_mask(a.v < b.v); }
static inline vreal operator<=(const vreal& a, const vreal& b) { return uvms_from_mask(a.v <= b.v); }
static inline vreal operator>(const vreal& a, const vreal& b) { return uvms_from_mask(a.v > b.v); }
static inline vreal operator>=(const vreal& a, const vreal& b) { return uvms_from_mask(a.v >= b.v); }
static inline vreal operator==(const vreal& a, const vreal& b) { return uvms_from_mask(a.v == b.v); }
static inline vreal operator!=(const vreal& a, const vreal& b) { return uvms_from_mask(a.v != b.v); }
static inline vreal operator!(const vreal& a) { return uvms_from_mask(a.v == lanes_t{}); }
// Both operands are always evaluated (as everything in SX-generated code is).
static inline vreal operator&&(const vreal& a, const vreal& b) {
  return uvms_from_mask((a.v != lanes_t{}) & (b.v != lanes_t{}));
}
static inline vreal operator||(const vreal& a, const vreal& b) {
  return uvms_from_mask((a.v != lanes_t{}) | (b.v != lanes_t{}));
}

// C's fmin / fmax: the smaller / larger operand, or the one that is not NaN.
static inline vreal fmin(const vreal& x, const vreal& y) {
  return vreal(uvms_blend((x.v < y.v) | (y.v != y.v), x.v, y.v));
}
static inline vreal fmax(const vreal& x, const vreal& y) {
  return vreal(uvms_blend((x.v > y.v) | (y.v != y.v), x.v, y.v));
}
UVMS_LANEWISE(floor, __builtin_floor)
UVMS_LANEWISE(ceil, __builtin_ceil)

// CasADi's helpers casadi_fmin, casadi_fmax and casadi_fabs pick their body by
// __STDC_VERSION__: before C99 a ternary on a comparison (`x<y ? x : y`, which lanes
// cannot take), else the C99 call (`fmin(x, y)`, overloaded above). C++ leaves the macro
// undefined, so it is set here to C99; the system headers the build includes are
// included first so that none of them sees it (glibc's only tests are for >= C99 or C11
// features, and features.h / sys/cdefs.h came with math.h above).
#include <omp.h>
#include <stddef.h>
#include <string.h>
#ifndef __STDC_VERSION__
#define __STDC_VERSION__ 199901L
#endif
