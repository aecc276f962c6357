/* Several generated solvers in one program (compiled as C and as C++): every solver of
 * FOR_EACH_SOLVER (from the generated "solvers.h") replays its test vectors on two workspaces at once,
 * one forwards and one backwards, the solvers taking turns tick by tick. Exit status 0 when every
 * answer matches its vector (status, and u within the solver's <NAME>_VECTOR_TOL). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "solvers.h"

typedef struct {
  int count;
  double *theta, *u;
  int *status;
  double max_err;
  int mismatches;
} vectors;

static int load(const char *path, int n_theta, int n_u, vectors *v) {
  char magic[32], name[96];
  int version, nt, nu, k, i, fast;
  FILE *f = fopen(path, "r");
  if (!f || fscanf(f, "%31s %d %95s %d %d %d", magic, &version, name, &nt, &nu, &v->count) != 6 || nt != n_theta ||
      nu != n_u) {
    fprintf(stderr, "bad vectors file %s\n", path);
    return -1;
  }
  v->theta = (double *)malloc(sizeof(double) * (size_t)v->count * n_theta);
  v->u = (double *)malloc(sizeof(double) * (size_t)v->count * n_u);
  v->status = (int *)malloc(sizeof(int) * (size_t)v->count);
  for (k = 0; k < v->count; ++k) {
    if (fscanf(f, "%d %d", &v->status[k], &fast) != 2) return -1;
    for (i = 0; i < n_theta; ++i)
      if (fscanf(f, "%lf", &v->theta[(long)k * n_theta + i]) != 1) return -1;
    for (i = 0; i < n_u; ++i)
      if (fscanf(f, "%lf", &v->u[(long)k * n_u + i]) != 1) return -1;
  }
  fclose(f);
  v->max_err = 0.0;
  v->mismatches = 0;
  return 0;
}

static void check(vectors *v, int k, int solved, const double *u, int n_u) {
  int i;
  if (solved != (v->status[k] == 0)) {
    ++v->mismatches;
    return;
  }
  if (!solved) return;
  for (i = 0; i < n_u; ++i) {
    double e = fabs(u[i] - v->u[(long)k * n_u + i]);
    if (!(e <= v->max_err)) v->max_err = e;
  }
}

#define DECLARE(name, NAME)                                                                  \
  static name##_workspace name##_ws[2];                                                      \
  static vectors name##_vec;                                                                 \
  static void name##_tick(int k) {                                                           \
    double u[NAME##_NU];                                                                     \
    int s, j = name##_vec.count - 1 - k;                                                     \
    if (k >= name##_vec.count) return;                                                       \
    s = name##_solve(&name##_ws[0], name##_vec.theta + (long)k * NAME##_NTHETA, u, NULL);    \
    check(&name##_vec, k, s == NAME##_SOLVED, u, NAME##_NU);                                 \
    s = name##_solve(&name##_ws[1], name##_vec.theta + (long)j * NAME##_NTHETA, u, NULL);    \
    check(&name##_vec, j, s == NAME##_SOLVED, u, NAME##_NU);                                 \
  }
FOR_EACH_SOLVER(DECLARE)

int main(int argc, char **argv) {
  int arg = 1, k, n = 0, failed = 0;
#define SETUP(name, NAME)                                                                               \
  if (arg >= argc || load(argv[arg++], NAME##_NTHETA, NAME##_NU, &name##_vec) != 0) return 2;           \
  if (name##_init(&name##_ws[0]) != 0 || name##_init(&name##_ws[1]) != 0) return 2;                     \
  if (name##_vec.count > n) n = name##_vec.count;
  FOR_EACH_SOLVER(SETUP)
  for (k = 0; k < n; ++k) {
#define TICK(name, NAME) name##_tick(k);
    FOR_EACH_SOLVER(TICK)
  }
#define REPORT(name, NAME)                                                                              \
  printf("SOLVER %s mismatches=%d max_err=%.17g\n", #name, name##_vec.mismatches, name##_vec.max_err);    \
  failed += name##_vec.mismatches > 0 || !(name##_vec.max_err <= NAME##_VECTOR_TOL);
  FOR_EACH_SOLVER(REPORT)
  return failed ? 1 : 0;
}
