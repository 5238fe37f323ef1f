/* Solve the exported MPC problem once from C: the deployment smoke test of wbmpc.
 *
 * Build (wbmpc.solver.deploy.build_example does this):
 *   gcc -O1 solve_once.c -I. -L. -lwbmpc_solver -o solve_once
 * Run:
 *   ./solve_once inputs.bin solution.bin
 * inputs.bin holds the solver inputs as float64, in order and dense: x0, p, lbx, ubx, lbg, ubg, lam_x0,
 * lam_g0 (sizes in layout.json). solution.bin receives the primal solution x (n_variables float64).
 */
#include <stdio.h>
#include <stdlib.h>

#include "wbmpc_solver.h"

static casadi_int numel(const casadi_int* sp) { return sp[0] * sp[1]; }

int main(int argc, char** argv) {
  if (argc != 3) {
    fprintf(stderr, "usage: %s inputs.bin solution.bin\n", argv[0]);
    return 2;
  }
  casadi_int n_in = wbmpc_solver_n_in(), n_out = wbmpc_solver_n_out();
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  if (wbmpc_solver_work(&sz_arg, &sz_res, &sz_iw, &sz_w)) return 1;
  const double** arg = malloc(sizeof(double*) * sz_arg);
  double** res = malloc(sizeof(double*) * sz_res);
  casadi_int* iw = malloc(sizeof(casadi_int) * sz_iw);
  double* w = malloc(sizeof(double) * sz_w);

  FILE* f = fopen(argv[1], "rb");
  if (!f) { fprintf(stderr, "cannot open %s\n", argv[1]); return 1; }
  double* inputs[16];
  for (casadi_int i = 0; i < n_in; ++i) {
    casadi_int n = numel(wbmpc_solver_sparsity_in(i));
    inputs[i] = malloc(sizeof(double) * (n > 0 ? n : 1));
    if ((casadi_int)fread(inputs[i], sizeof(double), n, f) != n) {
      fprintf(stderr, "%s: short read for input %s\n", argv[1], wbmpc_solver_name_in(i));
      return 1;
    }
    arg[i] = inputs[i];
  }
  fclose(f);
  double* outputs[16];
  for (casadi_int i = 0; i < n_out; ++i) {
    casadi_int n = numel(wbmpc_solver_sparsity_out(i));
    outputs[i] = malloc(sizeof(double) * (n > 0 ? n : 1));
    res[i] = outputs[i];
  }

  wbmpc_solver_incref();
  int mem = wbmpc_solver_checkout();
  int flag = wbmpc_solver(arg, res, iw, w, mem);
  wbmpc_solver_release(mem);
  wbmpc_solver_decref();
  if (flag) { fprintf(stderr, "solver returned %d\n", flag); return 1; }

  casadi_int nx = numel(wbmpc_solver_sparsity_out(0));
  FILE* out = fopen(argv[2], "wb");
  fwrite(outputs[0], sizeof(double), nx, out);
  fclose(out);
  printf("solved: %lld variables, cost %.9g\n", (long long)nx, outputs[1][0]);
  return 0;
}
