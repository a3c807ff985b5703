/* The condensed Gauss-Newton QP of one real-time iteration for one horizon, UVMS_NH
 * (defined before this text, with qp_driver.c's functions and UVMS_H's per-horizon
 * names): the library includes it once per horizon it holds (nmpc_expert.ocp), so the
 * expert's and the safety filter's horizons share one compiled model. Its sizes are
 * constants, so the compiler keeps each column of a product in registers.
 */

/* z (NZ) = sum_l a[l * stride] g[l] over the NX rows g[l] (NZ each) of a row-major G, in
 * increasing l; a column of the QP summed in registers. */
static void UVMS_H(uvms_rows)(const casadi_real* __restrict__ a, int stride,
                              const casadi_real* __restrict__ g, casadi_real* __restrict__ z) {
  int j, l;
  casadi_real acc[UVMS_NZ];
  for (j = 0; j < UVMS_NZ; ++j) acc[j] = 0;
  for (l = 0; l < UVMS_NX; ++l) {
    const casadi_real al = a[l * stride];
    const casadi_real* gl = g + l * UVMS_NZ;
    for (j = 0; j < UVMS_NZ; ++j) acc[j] += al * gl[j];
  }
  for (j = 0; j < UVMS_NZ; ++j) z[j] = acc[j];
}

/* Scratch of one QP build. */
typedef struct {
  uvms_interval_work iv;
  casadi_real fnext[UVMS_NX * UVMS_NH], phis[UVMS_NX * UVMS_NX * UVMS_NH];
  casadi_real gams[UVMS_NX * UVMS_NU * UVMS_NH];
  casadi_real nr[UVMS_NR * UVMS_NH], njr[UVMS_NR * UVMS_NX * UVMS_NH];
  casadi_real nc[UVMS_NC * UVMS_NH], njc[UVMS_NC * UVMS_NX * UVMS_NH];
  casadi_real xss[UVMS_NX], aref[UVMS_NU * UVMS_NH];
  casadi_real h[UVMS_NZ * UVMS_NZ], p[UVMS_NZ * UVMS_NZ], f[UVMS_NZ];
  casadi_real g[UVMS_NX * UVMS_NZ], gn[UVMS_NX * UVMS_NZ]; /* G_k row-major: NX rows of NZ */
  casadi_real gt[UVMS_NX * UVMS_NH * UVMS_NZ], ct[UVMS_NSOFT * UVMS_NZ];
  casadi_real e[UVMS_NX * UVMS_NH], ek[UVMS_NX];
  casadi_real lbc[UVMS_NSOFT], ubc[UVMS_NSOFT];
  casadi_real jg[UVMS_NR * UVMS_NZ], rr[UVMS_NR], wr[UVMS_NR];
  casadi_real cj[UVMS_NC * UVMS_NX], inv_scale[UVMS_NC];
} UVMS_H(uvms_qp_work);

/* The condensed QP (ocp.build_qp_builder: its inputs and outputs, in its order). */
static int UVMS_H(uvms_build_qp)(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                         casadi_real* w) {
  UVMS_H(uvms_qp_work)* v = (UVMS_H(uvms_qp_work)*)w;
  uvms_call c;
  const casadi_real *xbar = arg[0], *abar = arg[1], *theta = arg[2], *xd = arg[3];
  const casadi_real *vd = arg[4], *wt = arg[5], *d = arg[6];
  const int nx = UVMS_NX, nz = UVMS_NZ;
  casadi_real use_ss;
  int k, i, j, l, a, b;
  c.iw = iw;
  c.w = w + UVMS_OWN_W;
  use_ss = wt[UVMS_W_STEADYSTATE];
  for (k = 0; k < UVMS_NH; ++k) {
    if (uvms_interval(&c, &v->iv, xbar + k * nx, abar + k * UVMS_NU, theta, v->fnext + k * nx,
                      v->phis + k * nx * nx, v->gams + k * nx * UVMS_NU))
      return 1;
    for (i = 0; i < nx; ++i) v->fnext[k * nx + i] += d[i];
  }
  /* node 0 is the measured state: neither its cost nor its constraints depend on da */
  for (k = 0; k < UVMS_NH; ++k) {
    c.arg[0] = xbar + (k + 1) * nx;
    c.arg[1] = theta;
    c.arg[2] = xd + (k + 1) * 6;
    c.arg[3] = vd + (k + 1) * 6;
    c.res[0] = v->nr + k * UVMS_NR;
    c.res[1] = v->njr + k * UVMS_NR * nx;
    c.res[2] = v->nc + k * UVMS_NC;
    c.res[3] = v->njc + k * UVMS_NC * nx;
    if (UVMS_NODE(c.arg, c.res, c.iw, c.w, 0)) return 1;
  }
  for (k = 0; k < UVMS_NH; ++k) {
    if (uvms_steady(&c, &v->iv.terms, v->xss, xbar + k * nx, theta, vd + k * 6,
                    v->aref + k * UVMS_NU))
      return 1;
    for (i = 0; i < UVMS_NU; ++i) v->aref[k * UVMS_NU + i] = use_ss * v->aref[k * UVMS_NU + i];
  }
  /* R: H = diag(2 r), f = 2 r (abar - a_ref) */
  for (i = 0; i < nz * nz; ++i) v->h[i] = 0;
  for (i = 0; i < nz; ++i) {
    const casadi_real r2 = 2. * wt[UVMS_W_RU + i % UVMS_NU];
    v->h[i + i * nz] = r2;
    v->f[i] = r2 * (abar[i] - v->aref[i]);
  }
  for (i = 0; i < UVMS_NC; ++i) v->inv_scale[i] = 1. / wt[UVMS_W_SCALE + i];
  for (i = 0; i < nx * nz; ++i) v->g[i] = 0;
  for (i = 0; i < nx; ++i) v->ek[i] = 0;
  for (k = 0; k < UVMS_NH; ++k) {
    const casadi_real* phi = v->phis + k * nx * nx;
    const casadi_real* gam = v->gams + k * nx * UVMS_NU;
    const casadi_real* jr = v->njr + k * UVMS_NR * nx;
    const casadi_real* jc = v->njc + k * UVMS_NC * nx;
    const int used = k * UVMS_NU, cols = (k + 1) * UVMS_NU; /* G's nonzero columns */
    /* dx_{k+1} = Phi_k dx_k + Gamma_k da_k + defect_k (G's columns from k NU on are zero
     * before the step: the product leaves them zero, Gamma_k fills its block) */
    for (i = 0; i < nx; ++i) {
      casadi_real* gi = v->gn + i * nz;
      casadi_real s = 0;
      UVMS_H(uvms_rows)(phi + i, nx, v->g, gi);
      for (l = 0; l < nx; ++l) s += phi[i + l * nx] * v->ek[l];
      for (j = 0; j < UVMS_NU; ++j) gi[used + j] = gam[i + j * nx];
      v->e[k * nx + i] = s + (v->fnext[k * nx + i] - xbar[(k + 1) * nx + i]);
    }
    for (i = 0; i < nx * nz; ++i) v->g[i] = v->gn[i];
    for (i = 0; i < nx; ++i) v->ek[i] = v->e[k * nx + i];
    for (i = 0; i < nx * nz; ++i) v->gt[k * nx * nz + i] = v->g[i];
    /* the residual's Gauss-Newton terms: terminal node pose only (paper's E) */
    for (i = 0; i < 6; ++i) {
      v->wr[i] = k + 1 < UVMS_NH ? wt[UVMS_W_QX + i] : wt[UVMS_W_PX + i];
      v->wr[6 + i] = k + 1 < UVMS_NH ? wt[UVMS_W_QV + i] : 0.;
    }
    for (i = 0; i < UVMS_NR; ++i) {
      casadi_real s = 0;
      UVMS_H(uvms_rows)(jr + i, UVMS_NR, v->g, v->jg + i * nz);
      for (l = 0; l < nx; ++l) s += jr[i + l * UVMS_NR] * v->ek[l];
      v->rr[i] = v->wr[i] * (v->nr[k * UVMS_NR + i] + s);
    }
    /* H += (2 jg') (wr jg), f += (2 jg') (wr (r + jr e)), column by column */
    for (b = 0; b < cols; ++b) {
      casadi_real acc[UVMS_NZ];
      for (a = 0; a < nz; ++a) acc[a] = 0;
      for (i = 0; i < UVMS_NR; ++i) {
        const casadi_real* ji = v->jg + i * nz;
        const casadi_real t = v->wr[i] * ji[b];
        for (a = 0; a < nz; ++a) acc[a] += (2. * ji[a]) * t;
      }
      for (a = 0; a < cols; ++a) v->h[a + b * nz] += acc[a];
    }
    for (a = 0; a < cols; ++a) {
      casadi_real s = 0;
      for (i = 0; i < UVMS_NR; ++i) s += (2. * v->jg[i * nz + a]) * v->rr[i];
      v->f[a] += s;
    }
    /* the soft rows, normalized: C_k = S^-1 Jc G_k, c_k = S^-1 c + S^-1 Jc e_k */
    for (l = 0; l < nx; ++l)
      for (i = 0; i < UVMS_NC; ++i) v->cj[i + l * UVMS_NC] = v->inv_scale[i] * jc[i + l * UVMS_NC];
    for (i = 0; i < UVMS_NC; ++i) {
      casadi_real s = 0, cc;
      UVMS_H(uvms_rows)(v->cj + i, UVMS_NC, v->g, v->ct + (k * UVMS_NC + i) * nz);
      for (l = 0; l < nx; ++l) s += v->cj[i + l * UVMS_NC] * v->ek[l];
      cc = v->inv_scale[i] * v->nc[k * UVMS_NC + i] + s;
      v->lbc[k * UVMS_NC + i] = wt[UVMS_W_LOWER + i] - cc;
      v->ubc[k * UVMS_NC + i] = wt[UVMS_W_UPPER + i] - cc;
    }
  }
  for (b = 0; b < nz; ++b)
    for (a = 0; a < nz; ++a) v->p[a + b * nz] = 0.5 * (v->h[a + b * nz] + v->h[b + a * nz]);
  uvms_out(res[0], v->p, nz * nz);
  uvms_out(res[1], v->f, nz);
  uvms_out(res[2], v->ct, UVMS_NSOFT * nz);
  if (res[3])
    for (i = 0; i < nz; ++i) res[3][i] = -1. - abar[i];
  if (res[4])
    for (i = 0; i < nz; ++i) res[4][i] = 1. - abar[i];
  uvms_out(res[5], v->lbc, UVMS_NSOFT);
  uvms_out(res[6], v->ubc, UVMS_NSOFT);
  uvms_out(res[7], v->gt, UVMS_NH * nx * nz);
  uvms_out(res[8], v->e, UVMS_NH * nx);
  uvms_out(res[9], v->aref, UVMS_NH * UVMS_NU);
  return 0;
}

