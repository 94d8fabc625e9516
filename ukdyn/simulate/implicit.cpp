#include "ukdyn/simulate/implicit.hpp"

#include <cmath>

#ifdef UKDYN_HAVE_CVODE
#include <cvode/cvode.h>
#include <cvode/cvode_proj.h>
#include <nvector/nvector_serial.h>
#include <sundials/sundials_context.h>
#include <sunlinsol/sunlinsol_dense.h>
#include <sunmatrix/sunmatrix_dense.h>
#endif

namespace ukdyn::detail {

#ifndef UKDYN_HAVE_CVODE

bool cvode_available() { return false; }

ImplicitResult integrate_bdf(const ImplicitProblem&, std::vector<double>&, double,
                             const SimulationSettings&) {
  throw Error("integrator bdf: this ukdyn was built without SUNDIALS CVODE (libsundials-dev)");
}

#else

bool cvode_available() { return true; }

namespace {

struct UserData {
  const ImplicitProblem* p;
  std::vector<double> scratch;
};

int rhs_fn(realtype t, N_Vector y, N_Vector ydot, void* user) {
  auto* u = static_cast<UserData*>(user);
  u->p->rhs(t, N_VGetArrayPointer(y), N_VGetArrayPointer(ydot));
  for (std::size_t i = 0; i < u->p->size; ++i) {
    if (!std::isfinite(N_VGetArrayPointer(ydot)[i])) return 1;  // recoverable: CVODE cuts the step
  }
  return 0;
}

// Drift projection: corr = P(ycur) − ycur (the same projection the explicit integrators apply).
int proj_fn(realtype t, N_Vector ycur, N_Vector corr, realtype, N_Vector, void* user) {
  auto* u = static_cast<UserData*>(user);
  const double* y = N_VGetArrayPointer(ycur);
  double* c = N_VGetArrayPointer(corr);
  for (std::size_t i = 0; i < u->p->size; ++i) u->scratch[i] = y[i];
  u->p->project(t, u->scratch.data());
  for (std::size_t i = 0; i < u->p->size; ++i) {
    c[i] = u->scratch[i] - y[i];
    if (!std::isfinite(c[i])) return 1;
  }
  return 0;
}

// Owns the SUNDIALS objects (released in reverse order of creation).
struct Cvode {
  SUNContext ctx = nullptr;
  N_Vector y = nullptr;
  SUNMatrix A = nullptr;
  SUNLinearSolver LS = nullptr;
  void* mem = nullptr;
  ~Cvode() {
    if (mem) CVodeFree(&mem);
    if (LS) SUNLinSolFree(LS);
    if (A) SUNMatDestroy(A);
    if (y) N_VDestroy(y);
    if (ctx) SUNContext_Free(&ctx);
  }
};

}  // namespace

ImplicitResult integrate_bdf(const ImplicitProblem& p, std::vector<double>& x, double t0,
                             const SimulationSettings& s) {
  ImplicitResult res;
  UserData user{&p, std::vector<double>(p.size)};
  Cvode cv;
  auto check = [&](int flag, const char* what) {
    if (flag < 0)
      throw Error(std::string("CVODE: ") + what + " failed (" + CVodeGetReturnFlagName(flag) + ")");
  };
  if (SUNContext_Create(nullptr, &cv.ctx) != 0) throw Error("CVODE: SUNContext_Create failed");
  const auto n = static_cast<sunindextype>(p.size);
  cv.y = N_VNew_Serial(n, cv.ctx);
  for (std::size_t i = 0; i < p.size; ++i) N_VGetArrayPointer(cv.y)[i] = x[i];
  cv.mem = CVodeCreate(CV_BDF, cv.ctx);
  if (!cv.mem) throw Error("CVODE: CVodeCreate failed");
  check(CVodeInit(cv.mem, rhs_fn, t0, cv.y), "CVodeInit");
  check(CVodeSetUserData(cv.mem, &user), "CVodeSetUserData");
  check(CVodeSStolerances(cv.mem, s.rel_tol, s.abs_tol), "CVodeSStolerances");
  cv.A = SUNDenseMatrix(n, n, cv.ctx);
  cv.LS = SUNLinSol_Dense(cv.y, cv.A, cv.ctx);
  check(CVodeSetLinearSolver(cv.mem, cv.LS, cv.A), "CVodeSetLinearSolver");  // DQ Jacobian
  check(CVodeSetMaxNumSteps(cv.mem, 100'000'000L), "CVodeSetMaxNumSteps");
  check(CVodeSetInitStep(cv.mem, std::min(s.step, s.sample_dt)), "CVodeSetInitStep");
  if (p.project) check(CVodeSetProjFn(cv.mem, proj_fn), "CVodeSetProjFn");
  std::vector<double> xs(p.size);
  for (long i = 1; i < p.total_samples; ++i) {
    const double ts = p.sample_time(i);
    double t = t0;
    const int flag = CVode(cv.mem, ts, cv.y, &t, CV_NORMAL);
    if (flag < 0) {
      res.failed = true;
      res.message = std::string("CVODE failed at t = ") + std::to_string(t) + " (" +
                    CVodeGetReturnFlagName(flag) + ")";
      break;
    }
    for (std::size_t k = 0; k < p.size; ++k) xs[k] = N_VGetArrayPointer(cv.y)[k];
    if (p.project) p.project(ts, xs.data());  // the interpolated sample, as for dopri5
    if (!p.observe(ts, xs)) break;
  }
  long v = 0;
  CVodeGetNumSteps(cv.mem, &v);
  res.steps = v;
  CVodeGetNumErrTestFails(cv.mem, &v);
  res.error_test_failures = v;
  CVodeGetNumNonlinSolvConvFails(cv.mem, &v);
  res.nonlinear_failures = v;
  CVodeGetNumJacEvals(cv.mem, &v);
  res.jacobians = v;
  for (std::size_t k = 0; k < p.size; ++k) x[k] = N_VGetArrayPointer(cv.y)[k];
  return res;
}

#endif

}  // namespace ukdyn::detail
