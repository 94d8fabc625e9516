#include "ukdyn/output/control_output.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "run/run_observer.hpp"

namespace ukdyn {

ControlColumns::ControlColumns(const Scenario& sc, ClosedLoop* loop)
    : sc_(&sc),
      forces_(ControlModel{sc.system, servo_row_flags(*sc.system, sc.constraint_roles),
                           sc.actuators, sc.tau, sc.sim.uk},
              loop),
      motors_(sc.actuators) {
  const System& sys = *sc.system;
  const std::vector<bool>& servo = forces_.model().row_servo;
  row_names_ = sys.constraint_row_names();
  for (std::size_t i = 0; i < servo.size(); ++i)
    if (servo[i]) servo_names_.push_back(row_names_[i]);
  t0_ = sc.sim.t0;
  t_half_ = 0.5 * (sc.sim.t0 + sc.sim.t_end);
  if (forces_.has_split()) {
    for (const auto& c : sys.coordinate_names()) header_.push_back("Qp_" + c);
    for (const auto& c : sys.coordinate_names()) header_.push_back("Qs_" + c);
    header_.push_back("role_split_unique");
  }
  if (sc.actuators.count() > 0) {
    for (const auto& a : sc.actuators.names) header_.push_back("u_" + a);
    header_.push_back("act_residual");
    header_.insert(header_.end(), motors_.header().begin(), motors_.header().end());
  }
  if (loop != nullptr) {
    for (const auto& r : servo_names_) header_.push_back("e_" + r);
    for (const auto& r : servo_names_) header_.push_back("ed_" + r);
    if (forces_.servo_law() != nullptr) header_.push_back("servo_uncertainty");
  }
  u_prev_ = Vec::Zero(sc.actuators.count());
}

void ControlColumns::fill(double t, CVecRef q, CVecRef qd, const ForwardData& d, double* out) {
  forces_.evaluate(t, q, qd, d);
  if (forces_.has_split()) out = fill_split(t, out);
  if (forces_.actuated()) out = fill_actuators(t, qd, out);
  if (forces_.loop() != nullptr) fill_servo(t, out);
  if (peaks_.closure) {
    const ClosureForce& c = forces_.closure();
    peaks_.max_closure_force = io_detail::nanmax(peaks_.max_closure_force, c.magnitude);
    peaks_.max_squeeze_force =
        first_ ? c.squeeze : io_detail::nanmax(peaks_.max_squeeze_force, c.squeeze);
  }
  peaks_.max_abs_e = max_e_;
  peaks_.max_abs_e_second_half = max_e_half_;
  peaks_.max_abs_u = max_u_;
  peaks_.max_abs_udot = max_udot_;
  peaks_.saturation_max_over_limit = sat_over_;
  first_ = false;
  t_prev_ = t;
}

// Qp_, Qs_, role_split_unique; returns where the next columns go.
double* ControlColumns::fill_split(double t, double* out) {
  const RoleForceSplit& s = forces_.split();
  for (Index i = 0; i < s.Qp.size(); ++i) *out++ = s.Qp(i);
  for (Index i = 0; i < s.Qs.size(); ++i) *out++ = s.Qs(i);
  *out++ = s.unique ? 1.0 : 0.0;
  if (!s.unique && split_unique_) {
    split_unique_ = false;
    split_t_ = t;
    redundant_ = s.redundant_rows;
  }
  return out;
}

// u_, act_residual; returns where the next columns go.
double* ControlColumns::fill_actuators(double t, CVecRef qd, double* out) {
  const Vec& u = forces_.u();
  const double residual = forces_.actuation_residual();
  if (forces_.underactuated() && !underactuated_) {
    underactuated_ = true;
    residual_t_ = t;
  }
  if (forces_.saturated()) {
    if (!saturated_) sat_t_ = t;
    if (!first_ && t > t_prev_) peaks_.saturation_time += t - t_prev_;
    saturated_ = true;
    sat_over_ = std::max(sat_over_, forces_.over_limit());
  }
  max_residual_ = std::max(max_residual_, residual);
  for (Index j = 0; j < u.size(); ++j) *out++ = u(j);
  *out++ = residual;
  out = motors_.fill(t, qd, u, out);  // docs/motors.md
  // A u of no number makes the peak no number (null in summary.json, nan in a sweep's table),
  // never the largest finite u before it.
  max_u_ = u.allFinite() ? std::max(max_u_, u.size() ? u.cwiseAbs().maxCoeff() : 0.0)
                         : std::numeric_limits<double>::quiet_NaN();
  if (!first_ && t > t_prev_ && u.size())
    max_udot_ = std::max(max_udot_, (u - u_prev_).cwiseAbs().maxCoeff() / (t - t_prev_));
  u_prev_ = u;
  return out;
}

// e_, ed_, servo_uncertainty; returns where the next columns go.
double* ControlColumns::fill_servo(double t, double* out) {
  const Vec& e = forces_.e();
  const Vec& ed = forces_.ed();
  for (Index i = 0; i < e.size(); ++i) *out++ = e(i);
  for (Index i = 0; i < ed.size(); ++i) *out++ = ed(i);
  const double em = e.size() ? e.cwiseAbs().maxCoeff() : 0.0;
  max_e_ = std::max(max_e_, em);
  if (t >= t_half_) max_e_half_ = std::max(max_e_half_, em);
  const ServoLaw* law = forces_.servo_law();
  if (law == nullptr) return out;
  const double delta = forces_.uncertainty();
  *out++ = delta;
  if (delta > max_delta_ || first_) {
    max_delta_ = delta;
    max_delta_t_ = t;
  }
  const ServoLawSettings& ls = law->settings();
  if (ls.kind == ControlLawKind::robust && ls.rho > 0.0 && delta > ls.rho) {
    if (!rho_exceeded_) {
      rho_exceeded_ = true;
      rho_exceeded_t_ = t;
    }
    rho_exceeded_delta_ = std::max(rho_exceeded_delta_, delta);
  }
  return out;
}

void ControlColumns::set_plant(const System& plant) {
  forces_.set_plant(plant);
  peaks_.closure = forces_.has_closure();
}

std::vector<RunWarning> ControlColumns::warnings() const {
  std::vector<RunWarning> w;
  if (!split_unique_) {
    std::string rows;
    for (Index r : redundant_) rows += (rows.empty() ? "" : ", ") + row_names_[r];
    w.push_back({split_t_, "role_force_split",
                 "redundant constraint rows (" + rows +
                     "): the split Qc = Qp + Qs is not unique; the Qp_/Qs_ columns report the "
                     "least-norm multipliers (docs/control.md)"});
  }
  if (underactuated_) {
    std::string rows;
    for (const auto& r : servo_names_) rows += (rows.empty() ? "" : ", ") + r;
    w.push_back({residual_t_, "underactuated",
                 fmt::format("the actuators cannot realise the servo rows ({}): residual "
                             "‖B u + A_pᵀμ − Qc‖ up to {:.3e} (column act_residual)",
                             rows, max_residual_)});
  }
  if (rho_exceeded_) {
    const double rho = forces_.servo_law()->settings().rho;
    w.push_back(
        {rho_exceeded_t_, "rho_bound_exceeded",
         fmt::format("the plant's uncertainty ‖δ‖ = ‖A_s q̈ − (b_s + v)‖ exceeded the "
                     "robust law's bound rho = {:.6g} (first at t = {:.6g} s, up to {:.6g}, "
                     "{:.3g}× rho, at t = {:.6g} s): the assumption of the robust design "
                     "does not hold, its error bound is not guaranteed (docs/control.md)",
                     rho, rho_exceeded_t_, max_delta_, max_delta_ / rho, max_delta_t_)});
  }
  if (saturated_) {
    w.push_back(
        {sat_t_, "saturation",
         fmt::format("actuator limits reached: u clipped, up to {:.3e} over a limit", sat_over_)});
  }
  for (auto& m : motors_.warnings()) w.push_back(std::move(m));
  return w;
}

nlohmann::json ControlColumns::summary() const {
  nlohmann::json j;
  j["role_split_unique"] = split_unique_;
  j["servo_rows"] = servo_names_;
  if (sc_->actuators.count() > 0) {
    j["actuators"] = sc_->actuators.names;
    j["max_abs_u"] = max_u_;
    j["max_abs_udot"] = max_udot_;
    j["max_actuation_residual"] = max_residual_;
    j["underactuated"] = underactuated_;
  }
  if (forces_.loop() != nullptr) {
    const ServoLaw* law = forces_.servo_law();
    const bool user = law == nullptr;
    j["law"] = user ? std::string("user") : to_string(sc_->control->law.kind);
    if (user) j["max_actuation_residual"] = nullptr;  // not known: the user's law solved for u
    j["plant"] = sc_->control->plant ? sc_->control->plant->name : sc_->name;
    j["max_abs_e"] = max_e_;
    j["max_abs_e_second_half"] = max_e_half_;
    j["saturated"] = saturated_;
    if (law != nullptr) {
      j["max_uncertainty"] = max_delta_;
      j["max_uncertainty_t"] = max_delta_t_;
      const ServoLawSettings& ls = law->settings();
      if (ls.kind == ControlLawKind::robust) {
        j["rho"] = ls.rho;
        if (ls.rho > 0.0) j["uncertainty_over_rho"] = max_delta_ / ls.rho;
        j["rho_bound_exceeded"] = rho_exceeded_;
      }
    }
    if (saturated_) {
      j["saturation_first_t"] = sat_t_;
      j["saturation_max_over_limit"] = sat_over_;
      j["saturation_time"] = peaks_.saturation_time;
    }
    if (peaks_.closure && !first_) {
      j["max_closure_force"] = peaks_.max_closure_force;
      j["max_squeeze_force"] = peaks_.max_squeeze_force;
    }
  }
  return j;
}

std::vector<std::pair<std::string, std::vector<std::string>>> ControlColumns::figures() const {
  std::vector<std::pair<std::string, std::vector<std::string>>> f;
  const auto& names = sc_->system->coordinate_names();
  if (forces_.has_split()) {
    std::vector<std::string> p, s;
    for (const auto& c : names) p.push_back("Qp_" + c);
    for (const auto& c : names) s.push_back("Qs_" + c);
    f.push_back({"force_physical", p});
    f.push_back({"force_servo", s});
  }
  if (sc_->actuators.count() > 0) {
    std::vector<std::string> u;
    for (const auto& a : sc_->actuators.names) u.push_back("u_" + a);
    f.push_back({"actuators", u});
    for (auto& m : motors_.figures()) f.push_back(std::move(m));
  }
  if (forces_.loop() != nullptr) {
    std::vector<std::string> e;
    for (const auto& r : servo_names_) e.push_back("e_" + r);
    f.push_back({"servo_error", e});
  }
  return f;
}

}  // namespace ukdyn

namespace ukdyn {

std::unique_ptr<ControlRun> make_control_run(const Scenario& sc) {
  if (!sc.control) return nullptr;
  const ControlSpec& spec = *sc.control;
  const Scenario& plant_sc = spec.plant ? *spec.plant : sc;
  auto run = std::make_unique<ControlRun>();
  run->plant = physical_system(*plant_sc.system, plant_sc.constraint_roles);
  run->model = ControlModel{sc.system, servo_row_flags(*sc.system, sc.constraint_roles),
                            sc.actuators, sc.tau, sc.sim.uk};
  run->q0 = sc.q0;
  run->qd0 = sc.qd0;
  if (spec.initial_offset.size() > 0 && spec.initial_offset.cwiseAbs().maxCoeff() > 0.0)
    offset_start(run->model, sc.sim.t0, spec.initial_offset, run->q0, run->qd0);
  const System& p = *run->plant;
  if (p.rows() > 0) {
    Vec phi(p.rows());
    position_residuals(p, sc.sim.t0, run->q0, phi);
    if (phi.cwiseAbs().maxCoeff() > sc.initial_tolerance)
      throw Error(
          fmt::format("control: the start violates the plant's physical constraints by "
                      "{:.3e} (the model's and the plant's geometry differ?)",
                      phi.cwiseAbs().maxCoeff()));
  }
  run->law = std::make_unique<ServoLaw>(run->model, spec.law);
  const Vec dist = spec.disturbance;
  run->loop = std::make_unique<ClosedLoop>(run->model, *run->law, plant_sc.tau,
                                           [dist](double, VecRef d) { d = dist; });
  return run;
}

}  // namespace ukdyn
