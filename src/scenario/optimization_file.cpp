// Trajectory-optimisation problem files (ukdyn/scenario/optimization_file.hpp).
#include "ukdyn/scenario/optimization_file.hpp"

#include <Eigen/Geometry>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "output/csv_reader.hpp"
#include "scenario/yaml_loader.hpp"
#include "ukdyn/core/constraint_forces.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"

namespace ukdyn {

using io_detail::Loader;
using io_detail::Node;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

Index coordinate(const Loader& L, const Node& at, const System& sys, const std::string& name) {
  const auto& names = sys.coordinate_names();
  for (std::size_t i = 0; i < names.size(); ++i)
    if (names[i] == name) return static_cast<Index>(i);
  L.fail(at, "no coordinate named '" + name + "' in the scenario");
}

Index actuator(const Loader& L, const Node& at, const std::vector<std::string>& names,
               const std::string& name) {
  for (std::size_t i = 0; i < names.size(); ++i)
    if (names[i] == name) return static_cast<Index>(i);
  L.fail(at, "no actuator named '" + name + "'");
}

// Constraint rows by name: a row's own name (`grasp_ur_a_x`), or a block's name for all its rows
// (`grasp_ur_a` → every row named grasp_ur_a_*).
std::vector<Index> rows_named(const Loader& L, const Node& at, const System& sys,
                              const std::string& name) {
  const auto& names = sys.constraint_row_names();
  std::vector<Index> rows;
  for (std::size_t i = 0; i < names.size(); ++i)
    if (names[i] == name) return {static_cast<Index>(i)};
  for (std::size_t i = 0; i < names.size(); ++i)
    if (names[i].size() > name.size() + 1 && names[i].compare(0, name.size() + 1, name + "_") == 0)
      rows.push_back(static_cast<Index>(i));
  if (rows.empty()) L.fail(at, "no constraint row or block named '" + name + "'");
  return rows;
}

// A state: `zeros`, a list of n numbers, or a mapping {coordinate: value} (others: `fill`).
Vec state(const Loader& L, const Node& n, const System& sys, double fill) {
  const Index dof = sys.dof();
  if (n.node.IsScalar() && n.node.Scalar() == "zeros") return Vec::Zero(dof);
  if (n.node.IsSequence()) return L.vector(n, dof);
  if (!n.node.IsMap())
    L.fail(n, "expected `zeros`, a list of " + std::to_string(dof) +
                  " numbers or {coordinate: value}");
  Vec v = Vec::Constant(dof, fill);
  for (const auto& kv : n.node) {
    const std::string c = L.key(n, kv.first);
    const Node entry{kv.second, n.key + "." + c};
    v(coordinate(L, entry, sys, c)) = L.number(entry);
  }
  return v;
}

// Bounds {name: [lower, upper]} over coordinates or actuators.
template <class IndexOf>
void bounds(const Loader& L, const Node& n, Vec& lo, Vec& hi, Index size, IndexOf index_of) {
  if (!n.node.IsDefined()) return;
  if (!n.node.IsMap()) L.fail(n, "expected {name: [lower, upper]}");
  if (lo.size() == 0) lo = Vec::Constant(size, -kInf), hi = Vec::Constant(size, kInf);
  for (const auto& kv : n.node) {
    const std::string name = L.key(n, kv.first);
    const Node entry{kv.second, n.key + "." + name};
    const Index i = index_of(entry, name);
    if (!entry.node.IsSequence() || entry.node.size() != 2)
      L.fail(entry, "expected [lower, upper]");
    lo(i) = L.number(Node{entry.node[0], entry.key + "[0]"});
    hi(i) = L.number(Node{entry.node[1], entry.key + "[1]"});
    if (!(lo(i) < hi(i))) L.fail(entry, "the lower bound must be below the upper bound");
  }
}

// A whole number from lo to hi (checked before it is converted: 1e308 or 2.5 is refused, not cast).
int whole_number(const Loader& L, const Node& n, int lo, int hi) {
  const double v = L.number(n);
  if (!(v >= lo && v <= hi && v == std::floor(v)))
    L.fail(n, "expected a whole number from " + std::to_string(lo) + " to " + std::to_string(hi) +
                  ", got '" + n.node.Scalar() + "'");
  return static_cast<int>(v);
}

CollocationMethod method(const Loader& L, const Node& n) {
  if (!n.node.IsDefined()) return CollocationMethod::hermite_simpson;
  const std::string s = L.string(n);
  if (s == "hermite_simpson") return CollocationMethod::hermite_simpson;
  if (s == "trapezoidal") return CollocationMethod::trapezoidal;
  L.fail(n, "expected hermite_simpson or trapezoidal, got '" + s + "'");
}

void costs(const Loader& L, const Node& root, TrajectoryProblem& p) {
  const Node c = L.child(root, "costs", true);
  L.only_keys(c,
              {"effort", "power", "constraint_force", "constraint_rows", "smoothness", "duration"});
  if (const Node cr = L.child(c, "constraint_rows", false); cr.node.IsDefined()) {
    if (!cr.node.IsMap()) L.fail(cr, "expected {row or block: weight}");
    p.costs.multiplier = Vec::Zero(p.system->rows());
    for (const auto& kv : cr.node) {
      const std::string name = L.key(cr, kv.first);
      const Node entry{kv.second, cr.key + "." + name};
      const double w = L.number(entry);
      if (w < 0.0) L.fail(entry, "must be >= 0");
      for (const Index i : rows_named(L, entry, *p.system, name)) p.costs.multiplier(i) = w;
    }
  }
  const Index k = p.B.cols();
  if (const Node e = L.child(c, "effort", false); e.node.IsDefined()) {
    if (e.node.IsMap()) {
      p.costs.effort = Vec::Zero(k);
      for (const auto& kv : e.node) {
        const std::string a = L.key(e, kv.first);
        const Node entry{kv.second, e.key + "." + a};
        p.costs.effort(actuator(L, entry, p.actuator_names, a)) = L.number(entry);
      }
    } else {
      p.costs.effort = Vec::Constant(k, L.number(e));
    }
    if (p.costs.effort.minCoeff() < 0.0) L.fail(e, "effort weights must be >= 0");
  }
  auto weight = [&](const char* key) {
    const Node w = L.child(c, key, false);
    if (!w.node.IsDefined()) return 0.0;
    const double v = L.number(w);
    if (v < 0.0) L.fail(w, "must be >= 0");
    return v;
  };
  p.costs.power = weight("power");
  p.costs.constraint_force = weight("constraint_force");
  p.costs.smoothness = weight("smoothness");
  p.costs.duration = weight("duration");
  const bool any = (p.costs.effort.size() && p.costs.effort.maxCoeff() > 0) || p.costs.power > 0 ||
                   p.costs.constraint_force > 0 ||
                   (p.costs.multiplier.size() && p.costs.multiplier.maxCoeff() > 0) ||
                   p.costs.smoothness > 0 || p.costs.duration > 0;
  if (!any) L.fail(c, "no cost term has a positive weight");
}

void timing(const Loader& L, const Node& root, TrajectoryProblem& p) {
  const Node d = L.child(root, "duration", true);
  if (d.node.IsMap()) {
    L.only_keys(d, {"initial", "min", "max"});
    p.free_duration = true;
    p.duration = L.positive(L.child(d, "initial", true));
    p.min_duration = L.positive(L.child(d, "min", true));
    p.max_duration = L.positive(L.child(d, "max", true));
    if (!(p.min_duration <= p.duration && p.duration <= p.max_duration))
      L.fail(d, "expected min <= initial <= max");
  } else {
    p.duration = L.positive(d);
  }
  const Node n = L.child(root, "intervals", false);
  if (n.node.IsDefined()) p.intervals = whole_number(L, n, 1, 10000);
}

// `envelopes: motors`: each actuator's motor (docs/motors.md) seen at the joint. The motor's
// torque–speed line T_s (1 − |ω_m|/ω_0), ω_m = n ω_j, with τ_m = u/(n η) while motoring is
// |u| ≤ n η T_s (1 − |ω_j| / (ω_0/n)); its peak torque bounds |u| ≤ n η T_p. Braking (u ω_j < 0,
// τ_m = u η/n) would allow more torque: the motoring line is the conservative bound for both.
void motor_envelopes(const Loader& L, const Node& e, const Scenario& sc, bool actuated,
                     TrajectoryProblem& p) {
  if (actuated) L.fail(e, "`motors` takes the scenario's actuators: remove `actuated`");
  const Index k = p.B.cols();
  if (p.u_lower.size() == 0) p.u_lower = Vec::Constant(k, -kInf), p.u_upper = -p.u_lower;
  bool any = false;
  for (Index j = 0; j < k && j < static_cast<Index>(sc.actuators.motors.size()); ++j) {
    const auto& m = sc.actuators.motors[static_cast<std::size_t>(j)];
    if (!m) continue;
    const double scale = m->ratio * m->efficiency;
    if (std::isfinite(m->stall_torque) && std::isfinite(m->no_load_speed)) {
      p.envelopes.push_back({j, scale * m->stall_torque, m->no_load_speed / m->ratio});
      any = true;
    }
    if (std::isfinite(m->peak_torque)) {
      p.u_upper(j) = std::min(p.u_upper(j), scale * m->peak_torque);
      p.u_lower(j) = std::max(p.u_lower(j), -scale * m->peak_torque);
      any = true;
    }
  }
  if (!any)
    L.fail(e,
           "no actuator of the scenario has a motor with a stall torque and no-load speed or a "
           "peak torque");
}

void envelopes(const Loader& L, const Node& root, const Scenario& sc, bool actuated,
               TrajectoryProblem& p) {
  const Node e = L.child(root, "envelopes", false);
  if (!e.node.IsDefined()) return;
  if (e.node.IsScalar() && e.node.Scalar() == "motors")
    return motor_envelopes(L, e, sc, actuated, p);
  if (!e.node.IsSequence())
    L.fail(e, "expected `motors` or a list of {actuator, u_max, speed_max}");
  for (std::size_t i = 0; i < e.node.size(); ++i) {
    const Node item{e.node[i], e.key + "[" + std::to_string(i) + "]"};
    L.only_keys(item, {"actuator", "u_max", "speed_max"});
    const Node a = L.child(item, "actuator", true);
    p.envelopes.push_back({actuator(L, a, p.actuator_names, L.string(a)),
                           L.positive(L.child(item, "u_max", true)),
                           L.positive(L.child(item, "speed_max", true))});
  }
}

void ipopt(const Loader& L, const Node& root, IpoptSettings& s) {
  const Node n = L.child(root, "ipopt", false);
  if (!n.node.IsDefined()) return;
  L.only_keys(n, {"tol", "constr_viol_tol", "max_iter", "print_level", "lbfgs_memory", "options"});
  if (const Node o = L.child(n, "options", false); o.node.IsDefined()) {
    // Any IPOPT option, as the type IPOPT registers for it, checked here (name, type, range) so
    // that a bad one is named at its key before anything runs.
    if (!o.node.IsMap()) L.fail(o, "expected {IPOPT option: value}");
    for (const auto& kv : o.node) {
      const std::string name = L.key(o, kv.first);
      const Node entry{kv.second, o.key + "." + name};
      const std::string text = L.string(entry);
      double v = 0.0;
      const bool number = Loader::parse_number(text, v) && std::isfinite(v);
      if (const std::string why = add_ipopt_option(s, name, text, number ? &v : nullptr);
          !why.empty())
        L.fail(entry, why);
    }
  }
  auto positive = [&](const char* key, double fallback) {
    const Node k = L.child(n, key, false);
    return k.node.IsDefined() ? L.positive(k) : fallback;
  };
  auto whole = [&](const char* key, int lo, int hi, int fallback) {
    const Node k = L.child(n, key, false);
    return k.node.IsDefined() ? whole_number(L, k, lo, hi) : fallback;
  };
  s.tol = positive("tol", s.tol);
  s.dual_inf_tol = s.tol;
  s.constr_viol_tol = positive("constr_viol_tol", s.constr_viol_tol);
  s.max_iter = whole("max_iter", 0, 100000, s.max_iter);
  s.print_level = whole("print_level", 0, 12, s.print_level);
  s.lbfgs_memory = whole("lbfgs_memory", 1, 100, s.lbfgs_memory);
}

// The actuators: the scenario's (`actuators:`), or one per coordinate (B = I) if it has none.
void actuation(const Scenario& sc, TrajectoryProblem& p) {
  const System& sys = *sc.system;
  if (sc.actuators.count() > 0) {
    p.B = sc.actuators.B;
    p.actuator_names = sc.actuators.names;
    p.u_lower = -sc.actuators.limit;
    p.u_upper = sc.actuators.limit;
  } else {
    p.B = Mat::Identity(sys.dof(), sys.dof());
    p.actuator_names = sys.coordinate_names();
  }
}

// `guess: RUN/trajectory.csv`: a previous run's q, q̇ and u (a `ukdyn optimize` folder, or a
// `simulate` run with u_ columns), interpolated linearly in the fraction of the duration onto
// this problem's points (another mesh, method or duration is fine: a warm start).
void guess_from_csv(const Loader& L, const Node& at, const std::filesystem::path& file,
                    TrajectoryProblem& p) {
  std::istringstream text(read_input_text(file, "guess table", std::size_t{256} << 20));
  io_detail::CsvLines lines(text);
  std::string line;
  if (!lines.next(line)) L.fail(at, "the guess file is empty");
  const auto header = io_detail::split_csv_line(line);
  const auto& names = p.system->coordinate_names();
  std::vector<std::size_t> cols;
  auto column = [&](const std::string& name) {
    bool twice = false;
    const std::size_t c = io_detail::csv_column(header, name, twice);
    if (c == header.size()) L.fail(at, "the guess file has no column '" + name + "'");
    if (twice) L.fail(at, "the guess file has column '" + name + "' twice");
    cols.push_back(c);
  };
  column("t");
  for (const auto& c : names) column(c);
  for (const auto& c : names) column(c + "_dot");
  for (const auto& a : p.actuator_names) column("u_" + a);
  std::vector<Vec> rows;
  while (lines.next(line)) {
    const auto cells = io_detail::split_csv_line(line);
    if (cells.size() != header.size())
      L.fail(at, "the guess file's line " + std::to_string(lines.line_no()) + " has " +
                     std::to_string(cells.size()) + " cells, its header " +
                     std::to_string(header.size()));
    Vec r(static_cast<Index>(cols.size()));
    for (std::size_t i = 0; i < cols.size(); ++i)
      if (cols[i] >= cells.size() ||
          !io_detail::parse_csv_number(cells[cols[i]], r(static_cast<Index>(i))) ||
          !std::isfinite(r(static_cast<Index>(i))))
        L.fail(at, "the guess file's line " + std::to_string(lines.line_no()) +
                       " has no finite number in column '" +
                       header[cols[i] < header.size() ? cols[i] : 0] + "'");
    if (!rows.empty() && !(r(0) > rows.back()(0)))
      L.fail(at,
             "the guess file's times do not increase at line " + std::to_string(lines.line_no()));
    rows.push_back(std::move(r));
  }
  if (rows.size() < 2) L.fail(at, "the guess file needs at least two rows");
  const Index n = p.system->dof(), k = p.B.cols();
  const Index P =
      p.method == CollocationMethod::hermite_simpson ? 2 * p.intervals + 1 : p.intervals + 1;
  p.q_guess.resize(P, n), p.qd_guess.resize(P, n), p.u_guess.resize(P, k);
  const double t0 = rows.front()(0), span = rows.back()(0) - t0;
  std::size_t j = 0;
  for (Index i = 0; i < P; ++i) {
    const double t = t0 + span * static_cast<double>(i) / static_cast<double>(P - 1);
    while (j + 2 < rows.size() && rows[j + 1](0) < t) ++j;
    const double w = std::clamp((t - rows[j](0)) / (rows[j + 1](0) - rows[j](0)), 0.0, 1.0);
    const Vec r = (1.0 - w) * rows[j] + w * rows[j + 1];
    p.q_guess.row(i) = r.segment(1, n).transpose();
    p.qd_guess.row(i) = r.segment(1 + n, n).transpose();
    p.u_guess.row(i) = r.segment(1 + 2 * n, k).transpose();
  }
}

// The derivatives along q at fixed λ (6 rows: position, then rotation) of a weld's wrench on its
// frame b, and of b's origin (dp, 3 × n: J_b's velocity rows). The weld's rows
// (ukdyn/symbolic/frame_constraints.hpp) are p_a − p_b and ½ (X_ij − X_ji), X = R_aᵀR_b, for
// (i, j) = (2, 1), (0, 2), (1, 0); with a_i, b_j the columns of R_a, R_b and ḃ_j = ω_b × b_j,
// the rotation rows' rate along ω_b is ½ ω_b·(b_j × a_i − b_i × a_j), so w_b = G_bᵀλ is
//   f_b = −λ_p (constant),  m_b = ½ Σ λ_r (b_j × a_i − b_i × a_j).
// A frame's R = σ Q (Q a rotation, σ = Π |u_k|² over the quaternions u_k it hangs from, free
// bodies' and ball joints': the homogeneous matrix |u|² Rot(u/|u|), docs/free-bodies.md) moves
// along q_c as ∂R/∂q_c = ρ_c R + [ω_c]× R: the twist Jacobian's angular column is vee of the skew
// part of ∂R/∂q_c Rᵀ = ρ_c σ² I + σ² [ω_c]×, so ω_c = J_ω,c / σ² (σ² = tr(R Rᵀ)/3), and the radial
// rate is ρ_c = 2 u_c/|u|² for a coordinate of a quaternion u the frame hangs from (0 otherwise).
// So along q_c (α = ω_a,c, β = ω_b,c: ȧ_i = α × a_i + ρ_a a_i, ḃ_j = β × b_j + ρ_b b_j)
//   dm_b = ½ Σ λ_r ((β × b_j) × a_i + b_j × (α × a_i) − (β × b_i) × a_j − b_i × (α × a_j))
//          + (ρ_a + ρ_b) m_b.
// `quaternions`: the first coordinate of each quaternion (four in a row).
void weld_wrench_derivatives(const symbolic::FrameWrench& fw, const Vec& lambda, const Mat& Ja,
                             const Mat& Jb, const Vec& q, const std::vector<Index>& quaternions,
                             Eigen::Ref<Mat> dw, Eigen::Ref<Mat> dp) {
  dp = Jb.topRows<3>();
  const Eigen::Matrix3d &Ra = fw.rotation_a, &Rb = fw.rotation_b;
  const double sa2 = (Ra * Ra.transpose()).trace() / 3.0, sb2 = (Rb * Rb.transpose()).trace() / 3.0;
  constexpr int kPairs[3][2] = {{2, 1}, {0, 2}, {1, 0}};
  Vec3 mb = Vec3::Zero();
  for (int r = 0; r < 3; ++r) {
    const int i = kPairs[r][0], j = kPairs[r][1];
    mb += 0.5 * lambda(3 + r) * (Rb.col(j).cross(Ra.col(i)) - Rb.col(i).cross(Ra.col(j)));
  }
  Vec rho_a = Vec::Zero(q.size()), rho_b = Vec::Zero(q.size());
  for (const Index g : quaternions) {  // a frame hangs from u when its columns move it
    const double u2 = q.segment<4>(g).squaredNorm();
    for (auto [J, rho] : {std::pair{&Ja, &rho_a}, {&Jb, &rho_b}})
      if (J->middleCols<4>(g).cwiseAbs().maxCoeff() > 0.0)
        rho->segment<4>(g) = 2.0 * q.segment<4>(g) / u2;
  }
  for (Index c = 0; c < Ja.cols(); ++c) {
    const Vec3 alpha = Ja.block<3, 1>(3, c) / sa2, beta = Jb.block<3, 1>(3, c) / sb2;
    Vec3 dm = (rho_a(c) + rho_b(c)) * mb;
    for (int r = 0; r < 3; ++r) {
      const int i = kPairs[r][0], j = kPairs[r][1];
      const Vec3 ai = Ra.col(i), aj = Ra.col(j), bi = Rb.col(i), bj = Rb.col(j);
      dm += 0.5 * lambda(3 + r) *
            (beta.cross(bj).cross(ai) + bj.cross(alpha.cross(ai)) - beta.cross(bi).cross(aj) -
             bi.cross(alpha.cross(aj)));
    }
    dw.block<3, 1>(3, c) = dm;
  }
}

// The coordinates along which a grasp frame's rotation leaves the rotations: the homogeneous
// quaternion matrix R(u) = |u|² Rot(u/|u|) of a free body's or a ball joint's quaternion u
// (ukdyn/symbolic/free_body.hpp) has the radial derivative 2 u_c R. Found at q by a step of 1e-2
// in each coordinate: R Rᵀ stays I to rounding (≈ 1e-15) for a rotation, and moves by ≥ 1e-4 for
// a quaternion's coordinate (2 h u_c + h²).
std::vector<Index> scaling_coordinates(
    const Vec& q, const std::function<std::vector<Eigen::Matrix3d>(CVecRef)>& rotations) {
  std::vector<Index> out;
  Vec at = q;
  for (Index c = 0; c < q.size(); ++c) {
    at(c) = q(c) + 1e-2;
    for (const auto& R : rotations(at))
      if ((R * R.transpose() - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-8) {
        out.push_back(c);
        break;
      }
    at(c) = q(c);
  }
  return out;
}

// The quaternions among the scaling coordinates: runs of four in a row starting at a coordinate
// named *_qw (free bodies, ball and floating joints name them NAME_qw .. NAME_qz); the first
// coordinate of each into `quaternions`, and what is left (no such run) into `other`.
void quaternion_groups(const std::vector<Index>& scaled, const std::vector<std::string>& names,
                       std::vector<Index>& quaternions, std::vector<Index>& other) {
  auto has = [&](Index c) { return std::find(scaled.begin(), scaled.end(), c) != scaled.end(); };
  for (std::size_t k = 0; k < scaled.size(); ++k) {
    const Index c = scaled[k];
    const std::string& n = names[static_cast<std::size_t>(c)];
    const bool start = n.size() >= 3 && n.compare(n.size() - 3, 3, "_qw") == 0 && has(c + 1) &&
                       has(c + 2) && has(c + 3);
    if (start) {
      quaternions.push_back(c);
      k += 3;
    } else {
      other.push_back(c);
    }
  }
}

// `bounds: internal_wrench: {load: BODY.FRAME, force: F, torque: M}`: the welds whose frame b is
// the load's (its grasps, as the Wint_ columns find them: docs/frame-constraints.md) and Walker's
// internal part of their wrenches on it, (I − G⁺G) w, ukdyn/core/constraint_forces.hpp.
void internal_wrench_bound(const Loader& L, const Node& n, const Scenario& sc,
                           TrajectoryProblem& p) {
  if (!n.node.IsDefined()) return;
  L.only_keys(n, {"load", "force", "torque"});
  InternalWrenchBound b;
  const Node ln = L.child(n, "load", true);
  b.load = L.string(ln);
  const Node fn = L.child(n, "force", false), tn = L.child(n, "torque", false);
  if (fn.node.IsDefined()) b.max_force = L.positive(fn);
  if (tn.node.IsDefined()) b.max_torque = L.positive(tn);
  if (!fn.node.IsDefined() && !tn.node.IsDefined()) L.fail(n, "expected force, torque or both");
  struct Grasp {
    std::shared_ptr<const Constraint> owner;
    const symbolic::FrameWrenches* map;
    Index first_row;
  };
  std::vector<Grasp> grasps;
  const System& sys = *sc.system;
  for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
    const auto* f = dynamic_cast<const symbolic::FrameConstraint*>(sys.constraints()[c].get());
    if (f && f->wrench().kind() == symbolic::FrameConstraintDef::Kind::weld &&
        f->wrench().frame_b() == b.load)
      grasps.push_back({sys.constraints()[c], &f->wrench(), sys.constraint_row_offsets()[c]});
  }
  if (grasps.size() < 2)
    L.fail(ln, "'" + b.load + "' is held by " + std::to_string(grasps.size()) +
                   " weld(s) (frame b): an internal wrench needs two or more");
  b.grasps = static_cast<Index>(grasps.size());
  for (const auto& g : grasps) b.grasp_names.push_back(g.map->name());
  const std::vector<Index> scaled = scaling_coordinates(sc.q0, [&](CVecRef q) {
    std::vector<Eigen::Matrix3d> R;
    for (const auto& g : grasps) {
      const symbolic::FrameWrench fw = g.map->evaluate(q, Vec::Zero(g.map->rows()));
      R.push_back(fw.rotation_a);
      R.push_back(fw.rotation_b);
    }
    return R;
  });
  // The quaternions' columns exact (weld_wrench_derivatives()); any other scaling coordinate by
  // central differences.
  auto quaternions = std::make_shared<std::vector<Index>>();
  quaternion_groups(scaled, sys.coordinate_names(), *quaternions, b.differenced);
  // The grasps' wrenches w and points at (q, λ); with dw, dp non-null also their derivatives along
  // q at fixed λ (weld_wrench_derivatives()).
  auto grasp_wrenches = [grasps, quaternions](CVecRef q, CVecRef lambda, Vec& w,
                                              std::vector<Vec3>& points, Mat* dw, Mat* dp) {
    const Vec qv = q;
    const auto N = static_cast<Index>(grasps.size());
    w.resize(6 * N);
    points.clear();
    if (dw) dw->setZero(6 * N, q.size()), dp->resize(3 * N, q.size());
    Mat Ja, Jb;
    for (Index k = 0; k < N; ++k) {
      const auto& g = grasps[static_cast<std::size_t>(k)];
      const Vec lk = lambda.segment(g.first_row, g.map->rows());
      const symbolic::FrameWrench fw = g.map->evaluate(qv, lk);
      w.segment<3>(6 * k) = fw.force_b;
      w.segment<3>(6 * k + 3) = fw.moment_b;
      points.push_back(fw.position_b);
      if (!dw) continue;
      g.map->jacobians(qv, Ja, Jb);
      weld_wrench_derivatives(fw, lk, Ja, Jb, qv, *quaternions, dw->middleRows<6>(6 * k),
                              dp->middleRows<3>(3 * k));
    }
  };
  b.walker = [grasp_wrenches](CVecRef q, CVecRef lambda, VecRef out) {
    Vec w;
    std::vector<Vec3> points;
    grasp_wrenches(q, lambda, w, points, nullptr, nullptr);
    out = internal_wrench_walker(grasp_matrix(points, points.front()), w);
  };
  b.walker_dq = [grasp_wrenches, walker = b.walker, differenced = b.differenced](
                    CVecRef q, CVecRef lambda, VecRef out, Mat& dout) {
    Vec w;
    std::vector<Vec3> points;
    Mat dw, dp;
    grasp_wrenches(q, lambda, w, points, &dw, &dp);
    out = internal_wrench_walker(grasp_matrix(points, points.front()), w);
    dout = internal_wrench_walker_derivative(points, w, dp, dw);
    Vec qp = q, qm = q, wp(out.size()), wm(out.size());
    for (const Index c : differenced) {  // central differences (quaternion_groups())
      const double h = 1e-6 * (1.0 + std::abs(q(c)));
      qp(c) = q(c) + h;
      qm(c) = q(c) - h;
      walker(qp, lambda, wp);
      walker(qm, lambda, wm);
      dout.col(c) = (wp - wm) / (2.0 * h);
      qp(c) = qm(c) = q(c);
    }
  };
  p.internal_wrench_bounds.push_back(std::move(b));
}

std::string exact(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// An error of the scenario loaded with the waypoints appended from constraint `first` on: the
// message of the loader ("FILE:L:C: key 'constraints[K].a.xyz[0]': why") said at the waypoint's
// own key and line (constraints[K].a: waypoints[K - first].frame, .b.xyz: its position, .b.rpy:
// its orientation), since the text it names is one ukdyn wrote, not the user's file.
[[noreturn]] void waypoint_error(const Loader& L, const Node& wn, std::size_t first,
                                 const std::string& message) {
  const std::string tag = "key 'constraints[";
  const auto at = message.find(tag);
  std::size_t k = 0;
  std::size_t end = at == std::string::npos ? at : at + tag.size();
  while (end != std::string::npos && end < message.size() && std::isdigit(message[end]))
    k = 10 * k + static_cast<std::size_t>(message[end++] - '0');
  const auto close = end == std::string::npos ? end : message.find("': ", end);
  if (close == std::string::npos || message[end] != ']' || k < first || k - first >= wn.node.size())
    L.fail(wn, "a waypoint: " + message);
  const std::string rest = message.substr(end + 1, close - end - 1);  // ".a.xyz[0]" or ""
  const Node item{wn.node[k - first], wn.key + "[" + std::to_string(k - first) + "]"};
  // A key of the constraint written for the waypoint as the waypoint's key: "constraints[K].a.xyz"
  // as "waypoints[i].frame.xyz", ".b.xyz" as its position, ".b.rpy" as its orientation.
  const std::string written = "constraints[" + std::to_string(k) + "]";
  auto own_key = [&](const std::string& sub, Node* field) {
    const std::pair<const char*, const char*> fields[] = {
        {".a", "frame"}, {".b.xyz", "position"}, {".b.rpy", "orientation"}, {".name", "name"}};
    for (const auto& [from, to] : fields) {
      const std::size_t n = std::string(from).size();
      if (sub.compare(0, n, from) != 0 || (sub.size() > n && sub[n] != '.' && sub[n] != '['))
        continue;
      const Node f = L.child(item, to, false);
      if (field && f.node.IsDefined()) *field = f;
      return item.key + "." + to + sub.substr(n);
    }
    return item.key + sub;
  };
  std::string why = message.substr(close + 3);
  for (auto w = why.find(written); w != std::string::npos; w = why.find(written, w)) {
    auto e = why.find_first_of("' ", w);  // the key ends at its quote or a space
    if (e == std::string::npos) e = why.size();
    const std::string mapped =
        own_key(why.substr(w + written.size(), e - w - written.size()), nullptr);
    why.replace(w, e - w, mapped);
    w += mapped.size();
  }
  Node field = item;
  const std::string key = own_key(rest, &field);
  L.fail(Node{field.node, key}, why);
}

// `waypoints: [{name, frame, t, position, orientation}]`: each a ball constraint (a position) or a
// weld (with an orientation, roll-pitch-yaw as a frame offset's) between the frame and the world
// frame at the waypoint. They are appended to the scenario's constraints and the scenario loaded
// again with them (so the frame is resolved, and its rows and exact A built, as any frame
// constraint's: docs/frame-constraints.md); the waypoints' rows are then taken out of that copy.
void waypoints(const Loader& L, const Node& root, const Scenario& sc, TrajectoryProblem& p) {
  const Node wn = L.child(root, "waypoints", false);
  if (!wn.node.IsDefined()) return;
  if (!wn.node.IsSequence() || wn.node.size() == 0)
    L.fail(wn, "expected a list of {frame, t, position[, orientation, name]}");
  YAML::Node doc =
      YAML::Clone(io_detail::parse_scenario_yaml(read_scenario_text(sc.path), sc.path));
  const std::size_t first = doc["constraints"].IsSequence() ? doc["constraints"].size() : 0;
  std::vector<Waypoint> named;  // (their rows once the scenario is loaded with them)
  for (std::size_t i = 0; i < wn.node.size(); ++i) {
    const Node item{wn.node[i], wn.key + "[" + std::to_string(i) + "]"};
    L.only_keys(item, {"name", "frame", "t", "fraction", "position", "orientation"});
    const Node nn = L.child(item, "name", false);
    const std::string name = nn.node.IsDefined() ? L.name(nn) : "waypoint" + std::to_string(i + 1);
    for (const auto& other : named)
      if (other.name == name)
        L.fail(nn.node.IsDefined() ? nn : item, "waypoint '" + name + "' twice");
    const Node frame = L.child(item, "frame", true);
    if (!frame.node.IsScalar() && !frame.node.IsMap())
      L.fail(frame, "expected SUBSYSTEM.FRAME or {frame: SUBSYSTEM.FRAME, xyz: [..], rpy: [..]}");
    // Its time: t from the start, or a fraction of the duration (which a free duration needs).
    const Node tn = L.child(item, "t", false), fn = L.child(item, "fraction", false);
    if (tn.node.IsDefined() == fn.node.IsDefined())
      L.fail(item, "expected one of t (from the start) or fraction (of the duration)");
    const double t = tn.node.IsDefined() ? L.number(tn) : 0.0;
    const double fraction =
        fn.node.IsDefined() ? L.number(fn) : std::numeric_limits<double>::quiet_NaN();
    const Vec x = L.vector(L.child(item, "position", true), 3);
    const Node on = L.child(item, "orientation", false);
    YAML::Node c, b, xyz, rpy;
    c["type"] = on.node.IsDefined() ? "weld" : "ball";
    c["name"] = name;
    c["a"] = YAML::Clone(frame.node);
    b["frame"] = "world";
    for (Index k = 0; k < 3; ++k) xyz.push_back(exact(x(k)));
    b["xyz"] = xyz;
    if (on.node.IsDefined()) {
      const Vec r = L.vector(on, 3);
      for (Index k = 0; k < 3; ++k) rpy.push_back(exact(r(k)));
      b["rpy"] = rpy;
    }
    c["b"] = b;
    doc["constraints"].push_back(c);
    named.push_back({name, nullptr, t, fraction});
  }
  YAML::Emitter out;
  out << doc;
  LoadOptions opt;
  opt.check_initial = false;  // the start need not pass through the waypoints
  std::shared_ptr<const System> with;
  try {
    with = load_scenario_text(out.c_str(), sc.path, opt).system;
  } catch (const ScenarioError& e) {
    // The scenario loaded without the waypoints: what fails is a waypoint's frame, numbers or
    // name, reported at that waypoint's key of the problem file.
    waypoint_error(L, wn, first, e.what());
  }
  for (Waypoint& w : named) {
    // A waypoint's rows are NAME_x, NAME_y, NAME_z (then NAME_rx.. for an orientation), and row
    // names are unique: the first row names it (a prefix would also match waypoint NAME_b's).
    const std::string row = w.name + "_x";
    for (const auto& c : with->constraints())
      if (c->rows() > 0 && c->row_names().front() == row) w.rows = c;
    if (!w.rows) L.fail(wn, "waypoint '" + w.name + "': its rows were not built");
    p.waypoints.push_back(std::move(w));
  }
}

}  // namespace

OptimizationFile load_optimization_text(const std::string& text,
                                        const std::filesystem::path& path) {
  const Loader L(path);
  const Node root{io_detail::parse_scenario_yaml(text, path), ""};
  L.only_keys(root, {"ukdyn", "name", "description", "scenario", "method", "intervals", "duration",
                     "end", "costs", "bounds", "envelopes", "ipopt", "verify", "actuated",
                     "max_correction", "guess", "waypoints"});
  if (L.number(L.child(root, "ukdyn", true)) != 1)
    L.fail(L.child(root, "ukdyn", true), "expected 1");
  OptimizationFile f;
  f.path = path;
  f.hash = io_detail::scenario_text_hash(text);
  f.name = L.name(L.child(root, "name", true));
  const Node sn = L.child(root, "scenario", true);
  try {
    f.scenario = std::make_shared<Scenario>(load_scenario_file(path.parent_path() / L.string(sn)));
  } catch (const ScenarioError& e) {
    L.fail(sn, std::string("the scenario: ") + e.what());
  }
  const Scenario& sc = *f.scenario;
  if (sc.control)
    L.fail(sn,
           "the scenario has a control section: give the plain system (its physical constraints)");
  const System& sys = *sc.system;
  TrajectoryProblem& p = f.problem;
  p.system = sc.system;
  p.tau = sc.tau;
  p.uk = sc.sim.uk;
  p.t0 = sc.sim.t0;
  p.q_start = sc.q0;
  p.qd_start = sc.qd0;
  actuation(sc, p);
  if (const Node a = L.child(root, "actuated", false); a.node.IsDefined()) {
    // One input per listed coordinate (B: their columns of I), instead of the scenario's.
    if (!a.node.IsSequence() || a.node.size() == 0)
      L.fail(a, "expected a list of coordinate names");
    p.B = Mat::Zero(sys.dof(), static_cast<Index>(a.node.size()));
    p.actuator_names.clear();
    p.u_lower.resize(0), p.u_upper.resize(0);
    for (std::size_t i = 0; i < a.node.size(); ++i) {
      const Node item{a.node[i], a.key + "[" + std::to_string(i) + "]"};
      const std::string c = L.string(item);
      const Index j = coordinate(L, item, sys, c);
      if (p.B.row(j).sum() != 0.0) L.fail(item, "coordinate '" + c + "' is listed twice");
      p.B(j, static_cast<Index>(i)) = 1.0;
      p.actuator_names.push_back(c);
    }
  }
  p.method = method(L, L.child(root, "method", false));
  timing(L, root, p);
  const Node end = L.child(root, "end", true);
  L.only_keys(end, {"q", "qd"});
  p.q_end = state(L, L.child(end, "q", true), sys, std::numeric_limits<double>::quiet_NaN());
  const Node qd_end = L.child(end, "qd", false);
  p.qd_end = qd_end.node.IsDefined()
                 ? state(L, qd_end, sys, std::numeric_limits<double>::quiet_NaN())
                 : Vec::Zero(sys.dof());
  costs(L, root, p);
  if (const Node b = L.child(root, "bounds", false); b.node.IsDefined()) {
    L.only_keys(b, {"q", "qd", "u", "constraint_rows", "internal_wrench"});
    internal_wrench_bound(L, L.child(b, "internal_wrench", false), sc, p);
    auto coord = [&](const Node& at, const std::string& n) { return coordinate(L, at, sys, n); };
    bounds(L, L.child(b, "q", false), p.q_lower, p.q_upper, sys.dof(), coord);
    bounds(L, L.child(b, "qd", false), p.qd_lower, p.qd_upper, sys.dof(), coord);
    if (p.u_lower.size() == 0) p.u_lower = Vec::Constant(p.B.cols(), -kInf), p.u_upper = -p.u_lower;
    bounds(
        L, L.child(b, "u", false), p.u_lower, p.u_upper, p.B.cols(),
        [&](const Node& at, const std::string& n) { return actuator(L, at, p.actuator_names, n); });
  }
  envelopes(L, root, sc, L.child(root, "actuated", false).node.IsDefined(), p);
  if (const Node mc = L.child(root, "max_correction", false); mc.node.IsDefined())
    p.max_correction = L.positive(mc);
  ipopt(L, root, f.ipopt);
  waypoints(L, root, sc, p);
  if (const Node g = L.child(root, "guess", false); g.node.IsDefined()) {
    try {
      guess_from_csv(L, g, path.parent_path() / L.string(g), p);
    } catch (const ScenarioError& e) {
      const std::string m = e.what();
      if (m.find("key 'guess'") != std::string::npos) throw;
      L.fail(g, m);
    }
  }
  if (const Node v = L.child(root, "verify", false); v.node.IsDefined()) {
    const std::string s = L.string(v);
    if (s != "true" && s != "false") L.fail(v, "expected true or false");
    f.verify = s == "true";
  }
  try {
    validate(p);
  } catch (const Error& e) {
    // The message names the quantity; the place is the key that set it.
    const std::string m = e.what();
    const bool at_end = m.find("the end ") != std::string::npos;
    const bool at_bounds = m.find("outside its bounds") != std::string::npos;
    if (m.find("waypoint '") != std::string::npos) L.fail(L.child(root, "waypoints", true), m);
    if (m.find("the duration is free") != std::string::npos)
      L.fail(L.child(root, "duration", true), m);
    L.fail(at_end ? end : at_bounds ? L.child(root, "bounds", true) : sn, m);
  }
  return f;
}

OptimizationFile load_optimization_file(const std::filesystem::path& path) {
  return load_optimization_text(read_input_text(path, "problem file"), path);
}

}  // namespace ukdyn
