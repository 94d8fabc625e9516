#include "ukdyn/output/motor_output.hpp"

#include <fmt/format.h>

#include <cmath>
#include <limits>

namespace ukdyn {

void SampleIntegral::add(double t, double f) {
  if (count_ == 3) {  // the pair of intervals t_[0] .. t_[2] is complete: Simpson over it
    const double h1 = t_[1] - t_[0], h2 = t_[2] - t_[1];
    if (h1 > 0.0 && h2 > 0.0) {
      sum_ += (h1 + h2) / 6.0 *
              ((2.0 - h2 / h1) * f_[0] + (h1 + h2) * (h1 + h2) / (h1 * h2) * f_[1] +
               (2.0 - h1 / h2) * f_[2]);
    } else {
      sum_ += 0.5 * (h1 * (f_[0] + f_[1]) + h2 * (f_[1] + f_[2]));
    }
    tp_ = t_[1];
    fp_ = f_[1];
    has_prev_ = true;
    t_[0] = t_[2];
    f_[0] = f_[2];
    count_ = 1;
  }
  t_[static_cast<std::size_t>(count_)] = t;
  f_[static_cast<std::size_t>(count_)] = f;
  ++count_;
}

double SampleIntegral::value() const {
  if (count_ == 2) {
    // One open interval t_[0] .. t_[1]: from the quadratic through the sample before it, when
    // there is one (a pair was completed); else the trapezoid.
    const double h2 = t_[1] - t_[0];
    if (has_prev_) {
      const double h1 = t_[0] - tp_;
      if (h1 > 0.0 && h2 > 0.0)
        return sum_ + (-h2 * h2 * h2 / (6.0 * h1 * (h1 + h2)) * fp_ +
                       h2 * (3.0 * h1 + h2) / (6.0 * h1) * f_[0] +
                       h2 * (3.0 * h1 + 2.0 * h2) / (6.0 * (h1 + h2)) * f_[1]);
    }
    return sum_ + 0.5 * h2 * (f_[0] + f_[1]);
  }
  if (count_ == 3) {
    const double h1 = t_[1] - t_[0], h2 = t_[2] - t_[1];
    if (h1 > 0.0 && h2 > 0.0)
      return sum_ + (h1 + h2) / 6.0 *
                        ((2.0 - h2 / h1) * f_[0] + (h1 + h2) * (h1 + h2) / (h1 * h2) * f_[1] +
                         (2.0 - h1 / h2) * f_[2]);
    return sum_ + 0.5 * (h1 * (f_[0] + f_[1]) + h2 * (f_[1] + f_[2]));
  }
  return sum_;
}

MotorColumns::MotorColumns(const Actuators& actuators) : act_(&actuators) {
  for (std::size_t j = 0; j < actuators.motors.size(); ++j) {
    if (!actuators.motors[j]) continue;
    index_.push_back(static_cast<Index>(j));
    const std::string& a = actuators.names[j];
    for (const char* c :
         {"motor_torque_", "motor_speed_", "motor_current_", "motor_power_", "motor_margin_"})
      header_.push_back(c + a);
  }
  totals_.resize(index_.size());
}

double* MotorColumns::fill(double t, CVecRef qd, CVecRef u, double* out) {
  for (std::size_t k = 0; k < index_.size(); ++k) {
    const Index j = index_[k];
    const MotorSpec& m = *act_->motors[static_cast<std::size_t>(j)];
    const double omega_j = act_->B.col(j).dot(qd);
    const MotorPoint p = motor_point(m, u(j), omega_j);
    *out++ = p.torque;
    *out++ = p.omega_m;
    *out++ = p.current;
    *out++ = p.p_elec;
    *out++ = p.margin;
    Totals& s = totals_[k];
    if (!s.any) s.t_first = t;
    if (!s.any || std::abs(p.torque) > s.peak_torque) {
      s.peak_torque = std::abs(p.torque);
      s.peak_torque_t = t;
    }
    if (!s.any || std::abs(p.omega_m) > s.peak_speed) {
      s.peak_speed = std::abs(p.omega_m);
      s.peak_speed_t = t;
    }
    if (!s.any || p.margin < s.worst_margin) {
      s.worst_margin = p.margin;
      s.worst_margin_t = t;
      s.worst_is_speed = p.available < m.peak_torque;
    }
    const std::array<double, 8> f{p.torque * p.torque,
                                  p.omega_m * p.omega_m,
                                  p.p_elec,
                                  std::max(p.p_elec, 0.0),
                                  p.p_copper,
                                  p.p_gear,
                                  p.p_friction,
                                  u(j) * omega_j};
    for (std::size_t i = 0; i < f.size(); ++i) s.integral[i].add(t, f[i]);
    s.t_last = t;
    s.any = true;
  }
  return out;
}

nlohmann::json MotorColumns::summary() const {
  nlohmann::json all = nlohmann::json::object();
  for (std::size_t k = 0; k < index_.size(); ++k) {
    const auto j = static_cast<std::size_t>(index_[k]);
    const MotorSpec& m = *act_->motors[j];
    const Totals& s = totals_[k];
    const double T = s.t_last - s.t_first;
    const double rms_tau = T > 0.0 ? std::sqrt(s.integral[kTau2].value() / T) : s.peak_torque;
    const double rms_omega = T > 0.0 ? std::sqrt(s.integral[kOmega2].value() / T) : s.peak_speed;
    nlohmann::json e;
    e["ratio"] = m.ratio;
    e["efficiency"] = m.efficiency;
    e["reflected_inertia"] = m.ratio * m.ratio * m.rotor_inertia;
    e["peak_torque"] = s.peak_torque;
    e["peak_torque_t"] = s.peak_torque_t;
    e["rms_torque"] = rms_tau;
    e["peak_speed"] = s.peak_speed;
    e["peak_speed_t"] = s.peak_speed_t;
    e["rms_speed"] = rms_omega;
    e["energy_electrical"] = s.integral[kElec].value();
    e["energy_drawn"] = s.integral[kDrawn].value();
    e["energy_copper"] = s.integral[kCopper].value();
    e["energy_gear"] = s.integral[kGear].value();
    e["energy_friction"] = s.integral[kFriction].value();
    e["energy_joint"] = s.integral[kJoint].value();
    const bool finite = std::isfinite(s.worst_margin);
    e["worst_margin"] = finite ? nlohmann::json(s.worst_margin) : nlohmann::json(nullptr);
    e["worst_margin_t"] = s.worst_margin_t;
    e["worst_margin_limit"] = s.worst_is_speed ? "torque-speed line" : "peak torque";
    if (std::isfinite(m.continuous_torque)) e["rms_margin"] = 1.0 - rms_tau / m.continuous_torque;
    e["within_envelope"] = !(s.worst_margin < 0.0) &&
                           !(std::isfinite(m.continuous_torque) && rms_tau > m.continuous_torque);
    all[act_->names[j]] = e;
  }
  return all;
}

std::string MotorColumns::console_line() const {
  if (index_.empty()) return {};
  std::size_t worst = 0;
  for (std::size_t k = 1; k < totals_.size(); ++k)
    if (totals_[k].worst_margin < totals_[worst].worst_margin) worst = k;
  const Totals& s = totals_[worst];
  const std::string& name = act_->names[static_cast<std::size_t>(index_[worst])];
  if (!std::isfinite(s.worst_margin))
    return fmt::format("no torque limit given ({} motors)", index_.size());
  return fmt::format("worst margin {:.1f} % ({}, {}, at t = {:.6g} s){}", 100.0 * s.worst_margin,
                     name, s.worst_is_speed ? "torque-speed line" : "peak torque", s.worst_margin_t,
                     s.worst_margin < 0.0 ? ": OUTSIDE the envelope" : "");
}

std::vector<RunWarning> MotorColumns::warnings() const {
  std::vector<RunWarning> w;
  for (std::size_t k = 0; k < index_.size(); ++k) {
    const Totals& s = totals_[k];
    const auto j = static_cast<std::size_t>(index_[k]);
    if (s.worst_margin < 0.0)
      w.push_back(
          {s.worst_margin_t, "motor_envelope",
           fmt::format("the motor of actuator '{}' leaves its envelope: margin {:.3g} % "
                       "({}) at t = {:.6g} s (docs/motors.md)",
                       act_->names[j], 100.0 * s.worst_margin,
                       s.worst_is_speed ? "torque-speed line" : "peak torque", s.worst_margin_t)});
    const MotorSpec& m = *act_->motors[j];
    const double T = s.t_last - s.t_first;
    if (T > 0.0 && std::isfinite(m.continuous_torque)) {
      const double rms = std::sqrt(s.integral[kTau2].value() / T);
      if (rms > m.continuous_torque)
        w.push_back({s.t_last, "motor_continuous",
                     fmt::format("the motor of actuator '{}': RMS torque {:.6g} N·m over the run "
                                 "above its continuous torque {:.6g} N·m (docs/motors.md)",
                                 act_->names[j], rms, m.continuous_torque)});
    }
  }
  return w;
}

std::vector<std::pair<std::string, std::vector<std::string>>> MotorColumns::figures() const {
  std::vector<std::pair<std::string, std::vector<std::string>>> f;
  if (index_.empty()) return f;
  std::vector<std::string> tau, margin;
  for (Index j : index_) {
    tau.push_back("motor_torque_" + act_->names[static_cast<std::size_t>(j)]);
    margin.push_back("motor_margin_" + act_->names[static_cast<std::size_t>(j)]);
  }
  f.push_back({"motor_torque", tau});
  f.push_back({"motor_margin", margin});
  return f;
}

std::vector<Figure> MotorColumns::envelope_figures() const {
  std::vector<Figure> figs;
  for (Index j : index_) {
    const auto k = static_cast<std::size_t>(j);
    const MotorSpec& m = *act_->motors[k];
    const std::string& a = act_->names[k];
    Figure f;
    f.file = "motor_envelope_" + a + ".png";
    f.title = "Operating points of the motor of '" + a + "' over its envelope";
    f.ylabel = "|motor torque| [N·m]";
    f.xlabel = "|motor speed| [rad/s]";
    f.x_column = "motor_speed_" + a;
    f.columns = {"motor_torque_" + a};
    // Up to the no-load speed, or past the fastest sample.
    f.x_max = std::isfinite(m.no_load_speed)
                  ? 1.05 * std::max(m.no_load_speed, totals_[figs.size()].peak_speed)
                  : 0.0;
    // T_avail(x) = min(T_p, T_s (1 − x/ω_0)), 0 beyond ω_0 (numbers only: no text of the user's).
    const bool line = std::isfinite(m.stall_torque);
    const std::string ts =
        line && std::isfinite(m.no_load_speed)
            ? fmt::format("({:.17g}*(1 - x/{:.17g}))", m.stall_torque, m.no_load_speed)
            : fmt::format("({:.17g})", m.stall_torque);
    std::string env;
    if (line && std::isfinite(m.peak_torque)) {
      env = fmt::format("({:.17g} < {} ? {:.17g} : {})", m.peak_torque, ts, m.peak_torque, ts);
    } else if (line) {
      env = ts;
    } else if (std::isfinite(m.peak_torque)) {
      env = fmt::format("({:.17g})", m.peak_torque);
    }
    if (!env.empty()) f.functions.push_back({"(" + env + " > 0 ? " + env + " : 0)", "envelope"});
    if (std::isfinite(m.continuous_torque))
      f.functions.push_back(
          {fmt::format("({:.17g})", m.continuous_torque), "continuous torque (RMS limit)"});
    figs.push_back(std::move(f));
  }
  return figs;
}

}  // namespace ukdyn
