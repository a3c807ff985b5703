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
