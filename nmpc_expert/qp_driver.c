/* The model's side of one real-time iteration, and the steady input, around the
 * per-stage functions CasADi generated above this text (nmpc_expert.ocp, "the library"):
 * the model is theirs; this file and qp_condense.c hold only the linear algebra around
 * it, in loops over small dense matrices. Together they compute what the symbolic builder
 * they are tested against computes (ocp.build_qp_builder: the RK4 combinations, the
 * Taylor polynomials and the condensing's products summed in the same order), with two
 * writings of their own: the model's solves by Cholesky (the graph's CasADi solve is a
 * QR), the velocity Jacobian as terms_jac gives it.
 *
 * Written for CasADi's calling convention (arg, res, iw, w) and with casadi_real only, no
 * branch on a value: the library is also compiled with casadi_real a bundle of SIMD lanes
 * (uvms_env/vector/lanes.hpp), one robot per lane.
 *
 * Defined by the generator before this text: the sizes (UVMS_NQ, UVMS_NX, UVMS_NU,
 * UVMS_NS substeps, UVMS_NTH theta, UVMS_NW weights, UVMS_NC soft rows and UVMS_NR
 * residuals per node), the substep's constants (UVMS_DT, UVMS_DT_HALF, UVMS_DT_SIXTH), the
 * weight vector's offsets (UVMS_W_*), the stage functions' names (UVMS_TERMS,
 * UVMS_TERMS_JAC, UVMS_NODE, UVMS_STEADY_STATE, UVMS_OBJECT_STATE) and their largest
 * argument and result lists (UVMS_SUB_ARG, UVMS_SUB_RES), and the actuation: UVMS_B (NQ x
 * NU, column-major), UVMS_BT = B diag(tau_max), UVMS_TAU = tau_max (NU). Nothing here
 * depends on the horizon: qp_condense.c follows once per horizon the library holds, with
 * UVMS_NH defined, and each horizon's entry point after it.
 */

/* A per-horizon name: UVMS_H(uvms_build_qp) is uvms_build_qp_n5 where UVMS_NH is 5. */
#define UVMS_PASTE(name, h) name##_n##h
#define UVMS_NAMED(name, h) UVMS_PASTE(name, h)
#define UVMS_H(name) UVMS_NAMED(name, UVMS_NH)
#define UVMS_NZ (UVMS_NH * UVMS_NU)
#define UVMS_NSOFT (UVMS_NH * UVMS_NC)
#define UVMS_OWN_W (sizeof(UVMS_H(uvms_qp_work)) / sizeof(casadi_real))

#define UVMS_JCOLS (1 + 2 * UVMS_NQ + UVMS_NU) /* [B a + r, dr_s/dq, dr/dzeta, B diag(tau)] */

/* The stage functions' call: their arguments and results, and where their work begins. */
typedef struct {
  const casadi_real* arg[UVMS_SUB_ARG];
  casadi_real* res[UVMS_SUB_RES];
  casadi_int* iw;
  casadi_real* w;
} uvms_call;

/* z (NX x n) = x (NX x k) y (k x n), column-major; the sum over k in increasing order, as
 * CasADi's own product. A column of z is summed in registers (NX is a constant here). */
static void uvms_mul(int n, int k, const casadi_real* __restrict__ x,
                     const casadi_real* __restrict__ y, casadi_real* __restrict__ z) {
  int i, j, l;
  for (j = 0; j < n; ++j) {
    casadi_real acc[UVMS_NX];
    for (i = 0; i < UVMS_NX; ++i) acc[i] = 0;
    for (l = 0; l < k; ++l) {
      const casadi_real ylj = y[l + j * k];
      const casadi_real* xl = x + l * UVMS_NX;
      for (i = 0; i < UVMS_NX; ++i) acc[i] += xl[i] * ylj;
    }
    for (i = 0; i < UVMS_NX; ++i) z[j * UVMS_NX + i] = acc[i];
  }
}

/* Cholesky factor of the SPD NQ x NQ a (column-major), in place: its lower triangle; the
 * reciprocals of its diagonal in inv. */
static void uvms_cholesky(casadi_real* a, casadi_real* inv) {
  const int n = UVMS_NQ;
  int i, j, k;
  for (j = 0; j < n; ++j) {
    casadi_real d = a[j + j * n];
    for (k = 0; k < j; ++k) d -= a[j + k * n] * a[j + k * n];
    d = sqrt(d);
    a[j + j * n] = d;
    inv[j] = 1. / d;
    for (i = j + 1; i < n; ++i) {
      casadi_real s = a[i + j * n];
      for (k = 0; k < j; ++k) s -= a[i + k * n] * a[j + k * n];
      a[i + j * n] = s * inv[j];
    }
  }
}

/* b <- (L L')^-1 b for the m (<= UVMS_JCOLS) right-hand sides in the rows of b (row-major:
 * b[i * UVMS_JCOLS + c] is row i of column c), every column at once. */
static void uvms_solve(const casadi_real* __restrict__ l, const casadi_real* __restrict__ inv,
                       casadi_real* __restrict__ b, int m) {
  const int n = UVMS_NQ, w = UVMS_JCOLS;
  int c, i, k;
  for (i = 0; i < n; ++i) {
    casadi_real acc[UVMS_JCOLS];
    for (c = 0; c < m; ++c) acc[c] = b[i * w + c];
    for (k = 0; k < i; ++k) {
      const casadi_real lik = l[i + k * n];
      for (c = 0; c < m; ++c) acc[c] -= lik * b[k * w + c];
    }
    for (c = 0; c < m; ++c) b[i * w + c] = acc[c] * inv[i];
  }
  for (i = n - 1; i >= 0; --i) {
    casadi_real acc[UVMS_JCOLS];
    for (c = 0; c < m; ++c) acc[c] = b[i * w + c];
    for (k = i + 1; k < n; ++k) {
      const casadi_real lki = l[k + i * n];
      for (c = 0; c < m; ++c) acc[c] -= lki * b[k * w + c];
    }
    for (c = 0; c < m; ++c) b[i * w + c] = acc[c] * inv[i];
  }
}

/* B diag(tau_max) a + r, the generalized forces of normalized inputs a, into column 0 of
 * the row-major right-hand sides out (stride UVMS_JCOLS). */
static void uvms_forces(const casadi_real* a, const casadi_real* r, casadi_real* out) {
  int i, k;
  for (i = 0; i < UVMS_NQ; ++i) {
    casadi_real s = 0;
    for (k = 0; k < UVMS_NU; ++k) s += UVMS_BT[i + k * UVMS_NQ] * a[k];
    out[i * UVMS_JCOLS] = s + r[i];
  }
}

/* Scratch of one model evaluation (terms: M, r, q_dot; the Jacobian's four blocks). */
typedef struct {
  casadi_real m[UVMS_NQ * UVMS_NQ], r[UVMS_NQ], qdot[UVMS_NQ];
  casadi_real dqdot[UVMS_NQ * UVMS_NQ], tmap[UVMS_NQ * UVMS_NQ];
  casadi_real js[UVMS_NQ * UVMS_NQ], jz[UVMS_NQ * UVMS_NQ];
  casadi_real cols[UVMS_NQ * UVMS_JCOLS], inv[UVMS_NQ];
} uvms_terms;

/* x_dot = [T(q) zeta; M^-1 (B diag(tau_max) a + r)] at x. */
static int uvms_rhs(uvms_call* c, uvms_terms* t, const casadi_real* x, const casadi_real* a,
                    const casadi_real* theta, casadi_real* xdot) {
  int i;
  c->arg[0] = x;
  c->arg[1] = theta;
  c->res[0] = t->m;
  c->res[1] = t->r;
  c->res[2] = t->qdot;
  if (UVMS_TERMS(c->arg, c->res, c->iw, c->w, 0)) return 1;
  uvms_cholesky(t->m, t->inv);
  uvms_forces(a, t->r, t->cols);
  uvms_solve(t->m, t->inv, t->cols, 1);
  for (i = 0; i < UVMS_NQ; ++i) {
    xdot[i] = t->qdot[i];
    xdot[UVMS_NQ + i] = t->cols[i * UVMS_JCOLS];
  }
  return 0;
}

/* The rhs with its approximate Jacobians (ocp.build_f_jac): f, jx (NX x NX), ju (NX x NU). */
static int uvms_f_jac(uvms_call* c, uvms_terms* t, const casadi_real* x, const casadi_real* a,
                      const casadi_real* theta, casadi_real* f, casadi_real* jx,
                      casadi_real* ju) {
  int i, j;
  const int n = UVMS_NQ;
  c->arg[0] = x;
  c->arg[1] = theta;
  c->res[0] = t->m;
  c->res[1] = t->r;
  c->res[2] = t->qdot;
  c->res[3] = t->dqdot;
  c->res[4] = t->tmap;
  c->res[5] = t->js;
  c->res[6] = t->jz;
  if (UVMS_TERMS_JAC(c->arg, c->res, c->iw, c->w, 0)) return 1;
  uvms_cholesky(t->m, t->inv);
  uvms_forces(a, t->r, t->cols);
  for (i = 0; i < n; ++i) { /* row i: [B a + r, dr_s/dq, dr/dzeta, B diag(tau_max)] */
    casadi_real* row = t->cols + i * UVMS_JCOLS;
    for (j = 0; j < n; ++j) {
      row[1 + j] = t->js[i + j * n];
      row[1 + n + j] = t->jz[i + j * n];
    }
    for (j = 0; j < UVMS_NU; ++j) row[1 + 2 * n + j] = UVMS_BT[i + j * n];
  }
  uvms_solve(t->m, t->inv, t->cols, UVMS_JCOLS);
  for (i = 0; i < n; ++i) {
    const casadi_real* row = t->cols + i * UVMS_JCOLS;
    f[i] = t->qdot[i];
    f[n + i] = row[0];
    for (j = 0; j < n; ++j) {
      jx[i + j * UVMS_NX] = t->dqdot[i + j * n];
      jx[n + i + j * UVMS_NX] = row[1 + j];
      jx[i + (n + j) * UVMS_NX] = t->tmap[i + j * n];
      jx[n + i + (n + j) * UVMS_NX] = row[1 + n + j];
    }
    for (j = 0; j < UVMS_NU; ++j) {
      ju[i + j * UVMS_NX] = 0;
      ju[n + i + j * UVMS_NX] = row[1 + 2 * n + j];
    }
  }
  return 0;
}

/* Scratch of one interval. */
typedef struct {
  casadi_real xk[UVMS_NX], xs[UVMS_NX], k1[UVMS_NX], kk[UVMS_NX];
  casadi_real jx[UVMS_NX * UVMS_NX], ju[UVMS_NX * UVMS_NU];
  casadi_real m[UVMS_NX * UVMS_NX], m2[UVMS_NX * UVMS_NX], m3[UVMS_NX * UVMS_NX];
  casadi_real m4[UVMS_NX * UVMS_NX], sx[UVMS_NX * UVMS_NX], tu[UVMS_NX * UVMS_NX];
  casadi_real su[UVMS_NX * UVMS_NU], tmp[UVMS_NX * UVMS_NX], tmpu[UVMS_NX * UVMS_NU];
  uvms_terms terms;
} uvms_interval_work;

/* One shooting interval from x under a (ocp.build_interval): RK4 with UVMS_NS substeps,
 * end state xe; Phi (NX x NX), Gamma (NX x NU) chained per substep from the Jacobian at
 * its start, the 4th-order Taylor polynomials of expm(dt J) and of its integral. */
static int uvms_interval(uvms_call* c, uvms_interval_work* v, const casadi_real* x,
                         const casadi_real* a, const casadi_real* theta, casadi_real* xe,
                         casadi_real* phi, casadi_real* gam) {
  const int nx = UVMS_NX, nn = UVMS_NX * UVMS_NX, nu = UVMS_NX * UVMS_NU;
  int i, s, j;
  for (i = 0; i < nx; ++i) v->xk[i] = x[i];
  for (s = 0; s < UVMS_NS; ++s) {
    if (uvms_f_jac(c, &v->terms, v->xk, a, theta, v->k1, v->jx, v->ju)) return 1;
    /* k1 + 2 k2 + 2 k3 + k4, accumulated as the symbolic builder does */
    for (i = 0; i < nx; ++i) v->xs[i] = v->xk[i] + UVMS_DT_HALF * v->k1[i];
    if (uvms_rhs(c, &v->terms, v->xs, a, theta, v->kk)) return 1;
    for (i = 0; i < nx; ++i) {
      v->xs[i] = v->xk[i] + UVMS_DT_HALF * v->kk[i];
      v->k1[i] += 2. * v->kk[i];
    }
    if (uvms_rhs(c, &v->terms, v->xs, a, theta, v->kk)) return 1;
    for (i = 0; i < nx; ++i) {
      v->xs[i] = v->xk[i] + UVMS_DT * v->kk[i];
      v->k1[i] += 2. * v->kk[i];
    }
    if (uvms_rhs(c, &v->terms, v->xs, a, theta, v->kk)) return 1;
    for (i = 0; i < nx; ++i) {
      v->k1[i] += v->kk[i];
      v->xk[i] += UVMS_DT_SIXTH * v->k1[i];
    }
    /* step_x = I + m + m^2/2 + m^3/6 + m^4/24, step_u = (dt (I + m/2 + m^2/6 + m^3/24)) ju */
    for (i = 0; i < nn; ++i) v->m[i] = UVMS_DT * v->jx[i];
    uvms_mul(nx, nx, v->m, v->m, v->m2);
    uvms_mul(nx, nx, v->m2, v->m, v->m3);
    uvms_mul(nx, nx, v->m3, v->m, v->m4);
    for (j = 0; j < nx; ++j)
      for (i = 0; i < nx; ++i) {
        const int e = i + j * nx;
        const casadi_real one = i == j ? 1. : 0.;
        v->sx[e] = (((one + v->m[e]) + v->m2[e] / 2.) + v->m3[e] / 6.) + v->m4[e] / 24.;
        v->tu[e] = UVMS_DT * (((one + v->m[e] / 2.) + v->m2[e] / 6.) + v->m3[e] / 24.);
      }
    uvms_mul(UVMS_NU, nx, v->tu, v->ju, v->su);
    if (s == 0) { /* Phi = I, Gamma = 0 before the first substep */
      for (i = 0; i < nn; ++i) phi[i] = v->sx[i];
      for (i = 0; i < nu; ++i) gam[i] = v->su[i];
    } else {
      uvms_mul(nx, nx, v->sx, phi, v->tmp);
      for (i = 0; i < nn; ++i) phi[i] = v->tmp[i];
      uvms_mul(UVMS_NU, nx, v->sx, gam, v->tmpu);
      for (i = 0; i < nu; ++i) gam[i] = v->tmpu[i] + v->su[i];
    }
  }
  for (i = 0; i < nx; ++i) xe[i] = v->xk[i];
  return 0;
}

/* a_ss (NU) at x for the object twist vd (uvms_env.dynamics.local_model.build_steady_input):
 * the local model's bias at the rigid motion's velocities (UVMS_STEADY_STATE's x_ss),
 * balanced by the actuated inputs, clipped to the saturation. */
static int uvms_steady(uvms_call* c, uvms_terms* t, casadi_real* x_ss, const casadi_real* x,
                       const casadi_real* theta, const casadi_real* vd, casadi_real* a_ss) {
  int i, k;
  c->arg[0] = x;
  c->arg[1] = theta;
  c->arg[2] = vd;
  c->res[0] = x_ss;
  if (UVMS_STEADY_STATE(c->arg, c->res, c->iw, c->w, 0)) return 1;
  c->arg[0] = x_ss;
  c->arg[1] = theta;
  c->res[0] = t->m;
  c->res[1] = t->r;
  c->res[2] = t->qdot;
  if (UVMS_TERMS(c->arg, c->res, c->iw, c->w, 0)) return 1;
  for (k = 0; k < UVMS_NU; ++k) {
    casadi_real s = 0;
    for (i = 0; i < UVMS_NQ; ++i) s += UVMS_B[i + k * UVMS_NQ] * (-t->r[i]);
    a_ss[k] = fmin(fmax(s / UVMS_TAU[k], -1.), 1.);
  }
  return 0;
}

/* Scratch of one steady input. */
typedef struct {
  uvms_terms terms;
  casadi_real xss[UVMS_NX], a[UVMS_NU];
} uvms_steady_work;

#define UVMS_STEADY_W (sizeof(uvms_steady_work) / sizeof(casadi_real))

static void uvms_out(casadi_real* res, const casadi_real* v, int n) {
  int i;
  if (res)
    for (i = 0; i < n; ++i) res[i] = v[i];
}

/* a_ss of one state (the policy's first guess and holding input): x, theta, vd -> a_ss. */
static int uvms_steady_input(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                             casadi_real* w) {
  uvms_steady_work* v = (uvms_steady_work*)w;
  uvms_call c;
  c.iw = iw;
  c.w = w + UVMS_STEADY_W;
  if (uvms_steady(&c, &v->terms, v->xss, arg[0], arg[1], arg[2], v->a)) return 1;
  uvms_out(res[0], v->a, UVMS_NU);
  return 0;
}
