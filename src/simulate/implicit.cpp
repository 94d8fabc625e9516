#include "ukdyn/simulate/implicit.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#ifdef UKDYN_HAVE_CVODE
#ifdef UKDYN_HAVE_ARKODE
#include <arkode/arkode_arkstep.h>
#endif
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
bool arkode_available() { return false; }

ImplicitResult integrate_bdf(const ImplicitProblem&, std::vector<double>&, double,
                             const SimulationSettings&) {
  throw Error("integrator bdf: this ukdyn was built without SUNDIALS CVODE (libsundials-dev)");
}

ImplicitResult integrate_esdirk(const ImplicitProblem&, std::vector<double>&, double,
                                const SimulationSettings&) {
  throw Error("integrator esdirk: this ukdyn was built without SUNDIALS ARKODE (libsundials-dev)");
}

#else

bool cvode_available() { return true; }
#ifdef UKDYN_HAVE_ARKODE
bool arkode_available() { return true; }
#else
bool arkode_available() { return false; }
#endif

namespace {

struct UserData {
  const ImplicitProblem* p;
  std::vector<double> scratch;
  std::vector<double> f1 = std::vector<double>(scratch.size());  // the fallback's f(y + δ e_j)
  long jacobian_fallbacks = 0;
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

// Forward differences of f, column by column: J e_j ≈ (f(y + δ_j e_j) − f(y)) / δ_j with
// δ_j = √u · max(|y_j|, 1) (u the unit round-off; Dennis & Schnabel, Numerical Methods for
// Unconstrained Optimization, SIAM 1996, §5.4). The fallback of the exact Jacobian at a state
// where linearize() is not trusted. Allocates nothing (UserData's buffers).
int difference_jacobian(UserData& u, double t, const double* y, const double* fy, double* J) {
  const std::size_t n = u.p->size;
  const double sqrt_u = std::sqrt(std::numeric_limits<double>::epsilon());
  for (std::size_t i = 0; i < n; ++i) u.scratch[i] = y[i];
  for (std::size_t j = 0; j < n; ++j) {
    const double delta = sqrt_u * std::max(std::abs(y[j]), 1.0);
    u.scratch[j] = y[j] + delta;
    const double step = u.scratch[j] - y[j];  // the representable increment
    u.p->rhs(t, u.scratch.data(), u.f1.data());
    u.scratch[j] = y[j];
    for (std::size_t i = 0; i < n; ++i) {
      J[j * n + i] = (u.f1[i] - fy[i]) / step;
      if (!std::isfinite(J[j * n + i])) return 1;
    }
  }
  return 0;
}

// The Jacobian callback of CVODE (CVLsJacFn) and ARKStep (ARKLsJacFn): the exact ∂f/∂x of the
// problem into the dense matrix (column-major); where the problem says it is not trusted, forward
// differences at this call (counted). 1 (recoverable: the integrator cuts the step) for a
// non-finite entry.
int jac_fn(realtype t, N_Vector y, N_Vector fy, SUNMatrix Jac, void* user, N_Vector, N_Vector,
           N_Vector) {
  auto* u = static_cast<UserData*>(user);
  const std::size_t n = u->p->size;
  double* J = SM_DATA_D(Jac);
  std::fill(J, J + n * n, 0.0);
  const double* x = N_VGetArrayPointer(y);
  if (!u->p->jacobian(t, x, J)) {
    ++u->jacobian_fallbacks;
    return difference_jacobian(*u, t, x, N_VGetArrayPointer(fy), J);
  }
  for (std::size_t k = 0; k < n * n; ++k) {
    if (!std::isfinite(J[k])) return 1;
  }
  return 0;
}

#ifdef UKDYN_HAVE_ARKODE
// ARKStep's step post-processing (ARKStepSetPostprocessStepFn): the drift projection applied to
// the accepted step's end state in place. ARKODE 6.4 has no projection hook of CVODE's kind
// (ARKStepSetProjFn does not exist); the next step re-evaluates f at the projected state.
int postprocess_fn(realtype t, N_Vector y, void* user) {
  auto* u = static_cast<UserData*>(user);
  double* v = N_VGetArrayPointer(y);
  u->p->project(t, v);
  for (std::size_t i = 0; i < u->p->size; ++i) {
    if (!std::isfinite(v[i])) return 1;
  }
  return 0;
}

// Owns the ARKStep objects (released in reverse order of creation).
struct Arkode {
  SUNContext ctx = nullptr;
  N_Vector y = nullptr;
  SUNMatrix A = nullptr;
  SUNLinearSolver LS = nullptr;
  void* mem = nullptr;
  ~Arkode() {
    if (mem) ARKStepFree(&mem);
    if (LS) SUNLinSolFree(LS);
    if (A) SUNMatDestroy(A);
    if (y) N_VDestroy(y);
    if (ctx) SUNContext_Free(&ctx);
  }
};

#endif

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
  check(CVodeSetLinearSolver(cv.mem, cv.LS, cv.A), "CVodeSetLinearSolver");
  if (p.jacobian) check(CVodeSetJacFn(cv.mem, jac_fn), "CVodeSetJacFn");  // else CVODE's DQ
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
  res.jacobian_fallbacks = user.jacobian_fallbacks;
  for (std::size_t k = 0; k < p.size; ++k) x[k] = N_VGetArrayPointer(cv.y)[k];
  return res;
}

#ifdef UKDYN_HAVE_ARKODE
ImplicitResult integrate_esdirk(const ImplicitProblem& p, std::vector<double>& x, double t0,
                                const SimulationSettings& s) {
  ImplicitResult res;
  UserData user{&p, std::vector<double>(p.size)};
  Arkode ak;
  auto check = [&](int flag, const char* what) {
    if (flag < 0)
      throw Error(std::string("ARKODE: ") + what + " failed (" + ARKStepGetReturnFlagName(flag) +
                  ")");
  };
  if (SUNContext_Create(nullptr, &ak.ctx) != 0) throw Error("ARKODE: SUNContext_Create failed");
  const auto n = static_cast<sunindextype>(p.size);
  ak.y = N_VNew_Serial(n, ak.ctx);
  for (std::size_t i = 0; i < p.size; ++i) N_VGetArrayPointer(ak.y)[i] = x[i];
  ak.mem = ARKStepCreate(nullptr, rhs_fn, t0, ak.y, ak.ctx);  // fully implicit: fe = nullptr
  if (!ak.mem) throw Error("ARKODE: ARKStepCreate failed");
  check(ARKStepSetUserData(ak.mem, &user), "ARKStepSetUserData");
  // ESDIRK5(4)7L[2]SA2: 7 stages, explicit first stage, stiffly accurate, L-stable, order 5 with an
  // embedded order-4 error estimate (Kennedy & Carpenter, NASA/TM-2016-219173; SUNDIALS ARKODE 6.4
  // table ARKODE_ESDIRK547L2SA2_7_4_5). Chosen by measurement among ARKODE's order-5 DIRK tables
  // on the governor (docs/benchmarks-forces.md).
  check(ARKStepSetTableNum(ak.mem, ARKODE_ESDIRK547L2SA2_7_4_5, ARKODE_ERK_NONE),
        "ARKStepSetTableNum");
  check(ARKStepSStolerances(ak.mem, s.rel_tol, s.abs_tol), "ARKStepSStolerances");
  ak.A = SUNDenseMatrix(n, n, ak.ctx);
  ak.LS = SUNLinSol_Dense(ak.y, ak.A, ak.ctx);
  check(ARKStepSetLinearSolver(ak.mem, ak.LS, ak.A), "ARKStepSetLinearSolver");
  if (p.jacobian) check(ARKStepSetJacFn(ak.mem, jac_fn), "ARKStepSetJacFn");  // else ARKODE's DQ
  check(ARKStepSetMaxNumSteps(ak.mem, 100'000'000L), "ARKStepSetMaxNumSteps");
  check(ARKStepSetInitStep(ak.mem, std::min(s.step, s.sample_dt)), "ARKStepSetInitStep");
  // Predictor of the stage solutions: the interpolant of the last step at full order (method 1),
  // measured on the governor (docs/benchmarks-forces.md): 7 Newton iterations per step instead of
  // 17 with the default trivial predictor, and 62 instead of 7368 nonlinear-solver failures.
  check(ARKStepSetPredictorMethod(ak.mem, 1), "ARKStepSetPredictorMethod");
  // Lagrange interpolation (the outputs are step ends, see the stop times below): the Hermite
  // default costs one more f evaluation per step.
  check(ARKStepSetInterpolantType(ak.mem, ARK_INTERP_LAGRANGE), "ARKStepSetInterpolantType");
  if (p.project)
    check(ARKStepSetPostprocessStepFn(ak.mem, postprocess_fn), "ARKStepSetPostprocessStepFn");
  std::vector<double> xs(p.size);
  for (long i = 1; i < p.total_samples; ++i) {
    const double ts = p.sample_time(i);
    double t = t0;
    // Steps end on every sample: no interpolation of the output (which would not see the
    // projection of the step ends).
    check(ARKStepSetStopTime(ak.mem, ts), "ARKStepSetStopTime");
    const int flag = ARKStepEvolve(ak.mem, ts, ak.y, &t, ARK_NORMAL);
    if (flag < 0) {
      res.failed = true;
      res.message = std::string("ARKODE failed at t = ") + std::to_string(t) + " (" +
                    ARKStepGetReturnFlagName(flag) + ")";
      break;
    }
    for (std::size_t k = 0; k < p.size; ++k) xs[k] = N_VGetArrayPointer(ak.y)[k];
    if (!p.observe(ts, xs)) break;
  }
  long v = 0;
  ARKStepGetNumSteps(ak.mem, &v);
  res.steps = v;
  ARKStepGetNumErrTestFails(ak.mem, &v);
  res.error_test_failures = v;
  ARKStepGetNumNonlinSolvConvFails(ak.mem, &v);
  res.nonlinear_failures = v;
  ARKStepGetNumJacEvals(ak.mem, &v);
  res.jacobians = v;
  res.jacobian_fallbacks = user.jacobian_fallbacks;
  for (std::size_t k = 0; k < p.size; ++k) x[k] = N_VGetArrayPointer(ak.y)[k];
  return res;
}

#else
ImplicitResult integrate_esdirk(const ImplicitProblem&, std::vector<double>&, double,
                                const SimulationSettings&) {
  throw Error("integrator esdirk: this ukdyn was built without SUNDIALS ARKODE (libsundials-dev)");
}
#endif

#endif

}  // namespace ukdyn::detail
