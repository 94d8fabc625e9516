// Numeric frame constraints (ukdyn/symbolic/numeric_frame_constraint.hpp): the rows of
// frame_rows() evaluated from the frames' states, A and b by the chain rule.
#include "ukdyn/symbolic/numeric_frame_constraint.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <limits>
#include <set>

#include "core/lane_dual.hpp"
#include "symbolic/ex_helpers.hpp"
#include "symbolic/numeric_frame_lanes.hpp"
#include "tree/dual.hpp"
#include "ukdyn/model/column_derivatives.hpp"
#include "ukdyn/symbolic/free_body.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;
using K = FrameConstraintDef::Kind;
using tree::FrameState;

constexpr int kMaxRows = 6;

// Φ, D = ∂Φ/∂x and the second-order term Q = ẋᵀ H ẋ of the rows, x = (p_a, R_a, p_b, R_b):
// columns 0-2 p_a, 3-11 R_a (row-major, R(i, j) at 3 i + j), 12-14 p_b, 15-23 R_b. The scalar S
// is double (evaluate) or a dual number (tangent: forward-mode automatic differentiation).
template <class S>
struct RowValues {
  int m = 0;
  Eigen::Matrix<S, kMaxRows, 1> phi, Q;
  Eigen::Matrix<S, kMaxRows, 24> D;
};

constexpr int kPa = 0, kRa = 3, kPb = 12, kRb = 15;

// St: a frame's state with p, R, pd, Rd of scalar S (FrameState for doubles, DualFrame).
template <class S, class St>
void position_rows(const St& a, const St& b, RowValues<S>& r) {
  for (int k = 0; k < 3; ++k) {
    r.phi(r.m) = a.p(k) - b.p(k);
    r.D(r.m, kPa + k) = S(1.0);
    r.D(r.m, kPb + k) = S(-1.0);
    ++r.m;
  }
}

// Φ = ½ (X_ij − X_ji), X = R_aᵀ R_b (X_ij = Σ_k Ra_ki Rb_kj).
template <class S, class St>
void weld_row(const St& a, const St& b, int i, int j, RowValues<S>& r) {
  const S Xij = a.R.col(i).dot(b.R.col(j)), Xji = a.R.col(j).dot(b.R.col(i));
  r.phi(r.m) = 0.5 * (Xij - Xji);
  for (int k = 0; k < 3; ++k) {
    r.D(r.m, kRa + 3 * k + i) += 0.5 * b.R(k, j);
    r.D(r.m, kRa + 3 * k + j) -= 0.5 * b.R(k, i);
    r.D(r.m, kRb + 3 * k + j) += 0.5 * a.R(k, i);
    r.D(r.m, kRb + 3 * k + i) -= 0.5 * a.R(k, j);
  }
  // ẋᵀHẋ: ½ (Z_ij − Z_ji) with Z = 2 Ṙ_aᵀ Ṙ_b.
  r.Q(r.m) = a.Rd.col(i).dot(b.Rd.col(j)) - a.Rd.col(j).dot(b.Rd.col(i));
  ++r.m;
}

// Φ = (R_a u)·(R_b n).
template <class S, class St>
void hinge_row(const St& a, const St& b, const Eigen::Vector3d& u, const Eigen::Vector3d& n,
               RowValues<S>& r) {
  using V = Eigen::Matrix<S, 3, 1>;
  const V us = u.cast<S>(), ns = n.cast<S>();
  const V ua = a.R * us, nb = b.R * ns;
  r.phi(r.m) = ua.dot(nb);
  for (int k = 0; k < 3; ++k) {
    for (int i = 0; i < 3; ++i) {
      r.D(r.m, kRa + 3 * k + i) = u(i) * nb(k);
      r.D(r.m, kRb + 3 * k + i) = ua(k) * n(i);
    }
  }
  r.Q(r.m) = 2.0 * V(a.Rd * us).dot(V(b.Rd * ns));
  ++r.m;
}

// Φ = (R_a u)·e.
template <class S, class St>
void level_row(const St& a, const Eigen::Vector3d& u, const Eigen::Vector3d& e, RowValues<S>& r) {
  using V = Eigen::Matrix<S, 3, 1>;
  r.phi(r.m) = V(a.R * u.cast<S>()).dot(e.cast<S>());
  for (int k = 0; k < 3; ++k)
    for (int i = 0; i < 3; ++i) r.D(r.m, kRa + 3 * k + i) = S(e(k) * u(i));
  ++r.m;
}

// The leading rows of row_values() that are position_rows() (D = ±1 on p_a, p_b, nothing else)
// and are followed only by rows that do not read p_a, p_b: 3 for a weld, a ball and a hinge.
int position_row_count(const NumericFrameSpec& f) {
  return f.kind == K::weld || f.kind == K::ball || f.kind == K::hinge ? 3 : 0;
}

// The rows of frame_rows() (frame_constraints.cpp, rows_for) in the same order.
template <class S, class St>
void row_values(const NumericFrameSpec& f, const St& a, const St& b, RowValues<S>& r) {
  r.m = 0;
  r.phi.setZero();
  r.Q.setZero();
  r.D.setZero();
  switch (f.kind) {
    case K::weld:
      position_rows(a, b, r);
      weld_row(a, b, 2, 1, r);  // (R[7] − R[5]) / 2
      weld_row(a, b, 0, 2, r);  // (R[2] − R[6]) / 2
      weld_row(a, b, 1, 0, r);  // (R[3] − R[1]) / 2
      break;
    case K::ball:
      position_rows(a, b, r);
      break;
    case K::hinge: {
      position_rows(a, b, r);
      const auto [n1, n2] = perpendicular_pair(f.axis);
      hinge_row(a, b, f.axis, n1, r);
      hinge_row(a, b, f.axis, n2, r);
      break;
    }
    case K::level:
      if (f.vertical) {
        const auto [e1, e2] = perpendicular_pair(f.up);
        level_row(a, f.axis, e1, r);
        level_row(a, f.axis, e2, r);
      } else {
        level_row(a, f.axis, f.up, r);
      }
      break;
    case K::distance: {
      const Eigen::Matrix<S, 3, 1> d = a.p - b.p, dd = a.pd - b.pd;
      r.phi(0) = 0.5 * (d.dot(d) - f.length * f.length);
      for (int k = 0; k < 3; ++k) {
        r.D(0, kPa + k) = d(k);
        r.D(0, kPb + k) = -d(k);
      }
      r.Q(0) = dd.dot(dd);
      r.m = 1;
      break;
    }
  }
}

std::vector<std::string> row_names(const NumericFrameSpec& f) {
  const std::string& p = f.name;
  std::vector<std::string> n;
  auto position = [&] {
    for (const char* a : {"_x", "_y", "_z"}) n.push_back(p + a);
  };
  switch (f.kind) {
    case K::weld:
      position();
      for (const char* a : {"_rx", "_ry", "_rz"}) n.push_back(p + a);
      break;
    case K::ball:
      position();
      break;
    case K::hinge:
      position();
      n.push_back(p + "_n1");
      n.push_back(p + "_n2");
      break;
    case K::level:
      if (f.vertical) {
        n.push_back(p + "_v1");
        n.push_back(p + "_v2");
      } else {
        n.push_back(p);
      }
      break;
    case K::distance:
      n.push_back(p);
      break;
  }
  return n;
}

// One end, ready to evaluate: its columns in q and, for an expressions end, its tape:
// p (3), R (9), ∂p/∂q_c (3 per column), ∂R/∂q_c (9 per column), p̈|q̈=0 (3), R̈|q̈=0 (9).
struct End {
  NumericFrameEnd spec;
  std::vector<Index> cols;
  Tape tape;
  Index scratch = 0;   // doubles of slot it needs besides dp, dR: tree workspace or tape work+out
  Index n_system = 0;  // the system's coordinates (the tape's inputs)
  // An expressions end that is a frame fixed on a free body (free_body_frame below): its offset
  // (p = x + R(u) o, R = R(u) R_o) for end_state's closed form; the tape is kept for the
  // derivative passes.
  bool free_body = false;
  Eigen::Vector3d fb_o = Eigen::Vector3d::Zero();
  Eigen::Matrix3d fb_Ro = Eigen::Matrix3d::Identity();
  // R_o as a unit quaternion u_o and R_oᵀ o (free_body_pose), when R(u_o) is R_o to round-off.
  bool fb_quaternion = false;
  double fb_uo[4] = {1.0, 0.0, 0.0, 0.0};
  Eigen::Vector3d fb_of = Eigen::Vector3d::Zero();
  // The shape of its twist columns (weld_end_columns): the first unit_columns are translations
  // along the world axes (a free body's x, y, z: t_c = e_c); `scale`: s_c may be non-zero (a free
  // body, a tree with a ball or floating joint; revolute and prismatic joints give s_c = 0 exactly).
  Index unit_columns = 0;
  bool scale = true;
  // Its columns are consecutive coordinates (a tree's always; a free body's when its coordinates
  // are): weld_twist_rows walks A's columns by its stride.
  bool consecutive = false;
};

// Σ |c| over the terms c·(monomial) of a polynomial in `vars` (∞ if it is not one, or has other
// symbols): each term of the expanded sum evaluated with every variable at 1.
double coefficient_sum(const ex& d, const GiNaC::lst& vars, const GiNaC::exmap& ones) {
  const ex e = d.evalf().expand();
  if (!e.is_polynomial(vars)) return std::numeric_limits<double>::infinity();
  double sum = 0.0;
  auto add = [&](const ex& term) {
    const ex c = term.subs(ones).evalf();
    if (!GiNaC::is_a<GiNaC::numeric>(c) || !GiNaC::ex_to<GiNaC::numeric>(c).is_real()) {
      sum = std::numeric_limits<double>::infinity();
      return;
    }
    sum += std::abs(GiNaC::ex_to<GiNaC::numeric>(c).to_double());
  };
  if (GiNaC::is_a<GiNaC::add>(e)) {
    for (const ex& t : e) add(t);
  } else {
    add(e);
  }
  return sum;
}

// B(a, b) = B(b, a) with B(u, u) = R(u) (quaternion_rotation, quadratic in u = (w, x, y, z)): the
// polarisation of R, so that ∂R/∂u_k = 2 B(e_k, u), Ṙ = 2 B(u, u̇) and R̈|ü=0 = 2 B(u̇, u̇).
// Into B's column-major storage (a Matrix3d's data()).
inline void quaternion_bilinear(const double* a, const double* b, double* B) {
  const double ww = a[0] * b[0], xx = a[1] * b[1], yy = a[2] * b[2], zz = a[3] * b[3];
  const double xy = a[1] * b[2] + a[2] * b[1], xz = a[1] * b[3] + a[3] * b[1];
  const double yz = a[2] * b[3] + a[3] * b[2], wx = a[0] * b[1] + a[1] * b[0];
  const double wy = a[0] * b[2] + a[2] * b[0], wz = a[0] * b[3] + a[3] * b[0];
  B[0] = ww + xx - yy - zz;
  B[3] = xy - wz;
  B[6] = xz + wy;
  B[1] = xy + wz;
  B[4] = ww - xx + yy - zz;
  B[7] = yz - wx;
  B[2] = xz - wy;
  B[5] = yz + wx;
  B[8] = ww - xx - yy + zz;
}
Eigen::Matrix3d quaternion_bilinear(const double* a, const double* b) {
  Eigen::Matrix3d B;
  quaternion_bilinear(a, b, B.data());
  return B;
}

// Whether the pose x (p, then R row-major) over the end's 7 coordinates q is a frame fixed on a
// free body, p = (q0, q1, q2) + R(u) o and R = R(u) R_o with u = (q3 .. q6) and R(u)
// free_body.hpp's quaternion_rotation: o and R_o are read at q = (0, 0, 0, 1, 0, 0, 0), then each
// of the 12 entries is checked as a polynomial identity (its coefficients zero to round-off).
void free_body_frame(End& end, const std::vector<GiNaC::symbol>& q, const std::vector<ex>& x) {
  if (q.size() != 7 || x.size() != 12) return;
  GiNaC::exmap at_identity, ones;
  GiNaC::lst vars;
  for (std::size_t j = 0; j < 7; ++j) {
    at_identity[q[j]] = j == 3 ? 1 : 0;
    ones[q[j]] = 1;
    vars.append(q[j]);
  }
  double off[12];
  for (std::size_t i = 0; i < 12; ++i) {
    const ex v = x[i].subs(at_identity).evalf();
    if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real()) return;
    off[i] = GiNaC::ex_to<GiNaC::numeric>(v).to_double();
  }
  const std::array<ex, 9> Ru = quaternion_rotation(q[3], q[4], q[5], q[6]);
  double scale = 1.0;
  for (const double v : off) scale += std::abs(v);
  for (std::size_t i = 0; i < 3; ++i) {
    ex pred = q[i];
    for (std::size_t j = 0; j < 3; ++j) pred += Ru[3 * i + j] * off[j];
    if (!(coefficient_sum(x[i] - pred, vars, ones) <= 1e-12 * scale)) return;
    for (std::size_t j = 0; j < 3; ++j) {
      ex r = 0;
      for (std::size_t l = 0; l < 3; ++l) r += Ru[3 * i + l] * off[3 + 3 * l + j];
      if (!(coefficient_sum(x[3 + 3 * i + j] - r, vars, ones) <= 1e-12 * scale)) return;
    }
  }
  end.free_body = true;
  end.unit_columns = 3;
  for (int i = 0; i < 3; ++i) end.fb_o(i) = off[i];
  for (int i = 0; i < 9; ++i) end.fb_Ro(i / 3, i % 3) = off[3 + i];
  const Eigen::Quaterniond uo = Eigen::Quaterniond(end.fb_Ro).normalized();
  const double c[4] = {uo.w(), uo.x(), uo.y(), uo.z()};
  if ((quaternion_bilinear(c, c) - end.fb_Ro).cwiseAbs().maxCoeff() <= 1e-14) {
    end.fb_quaternion = true;
    std::copy(c, c + 4, end.fb_uo);
    end.fb_of = end.fb_Ro.transpose() * end.fb_o;
  }
}

// a ⊗ b (Hamilton's product) of quaternions (w, x, y, z): R(a ⊗ b) = R(a) R(b) for
// quaternion_rotation's homogeneous R (Shoemake 1985).
inline void quaternion_product(const double* a, const double* b, double* out) {
  out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
  out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
  out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
  out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
}

// A free-body end's pose and rates (free_body_frame) in closed form; the body's coordinates x,
// u = (w, x, y, z) into xq (7), the offset R(u) o returned (p = x + R(u) o). With the quaternion
// u_o of R_o (End::fb_uo) the frame's rotation is R(u) R_o = R(u ⊗ u_o) = B(u', u') with
// u' = u ⊗ u_o, and by polarisation of R(a ⊗ u_o) = R(a) R_o its rates are Ṙ R_o = 2 B(u', u̇')
// and R̈ R_o = 2 B(u̇', u̇'), u̇' = u̇ ⊗ u_o (the 2 in u̇': exact): two quaternion products instead of
// three 3 × 3 ones; the offset is then (R(u) R_o) R_oᵀ o. `position`: p and ṗ too (evaluate()'s
// weld rows read neither).
Eigen::Vector3d free_body_pose(const End& e, CVecRef q, CVecRef qd, FrameState& s, double* xq,
                               bool position = true) {
  double v[7];
  for (std::size_t c = 0; c < 7; ++c) {
    xq[c] = q(e.cols[c]);
    v[c] = qd(e.cols[c]);
  }
  const double* u = xq + 3;
  const double* ud = v + 3;
  const Eigen::Vector3d x(xq[0], xq[1], xq[2]);
  if (e.fb_quaternion) {
    double uf[4], udf[4], udf2[4];
    quaternion_product(u, e.fb_uo, uf);
    quaternion_product(ud, e.fb_uo, udf);
    for (int k = 0; k < 4; ++k) udf2[k] = 2.0 * udf[k];
    quaternion_bilinear(uf, uf, s.R.data());
    quaternion_bilinear(uf, udf2, s.Rd.data());
    quaternion_bilinear(udf, udf2, s.Rdd.data());
    const Eigen::Vector3d r = s.R * e.fb_of;
    if (position) {
      s.p = x + r;
      s.pd = Eigen::Vector3d(v[0], v[1], v[2]) + s.Rd * e.fb_of;
    }
    s.pdd = s.Rdd * e.fb_of;
    return r;
  }
  const Eigen::Matrix3d R = quaternion_bilinear(u, u);
  const Eigen::Matrix3d Rd = 2.0 * quaternion_bilinear(u, ud);
  const Eigen::Matrix3d Rdd = 2.0 * quaternion_bilinear(ud, ud);
  const Eigen::Vector3d r = R * e.fb_o;
  s.p = x + r;
  s.R = R * e.fb_Ro;
  s.pd = Eigen::Vector3d(v[0], v[1], v[2]) + Rd * e.fb_o;
  s.Rd = Rd * e.fb_Ro;
  s.pdd = Rdd * e.fb_o;
  s.Rdd = Rdd * e.fb_Ro;
  return r;
}

// A free-body end's state (free_body_frame) in closed form: what its tape computes, without it.
void free_body_state(const End& e, CVecRef q, CVecRef qd, FrameState& s) {
  double x[7];
  free_body_pose(e, q, qd, s, x);
  const double* u = x + 3;
  for (Index c = 0; c < 3; ++c) {
    s.dp.col(c).setZero();
    s.dp(c, c) = 1.0;
    s.dR.col(c).setZero();
  }
  for (Index k = 0; k < 4; ++k) {
    double ek[4] = {0.0, 0.0, 0.0, 0.0};
    ek[k] = 1.0;
    const Eigen::Matrix3d dRk = 2.0 * quaternion_bilinear(ek, u);
    s.dp.col(3 + k) = dRk * e.fb_o;
    const Eigen::Matrix3d dRf = dRk * e.fb_Ro;
    for (int i = 0; i < 9; ++i) s.dR(i, 3 + k) = dRf(i / 3, i % 3);
  }
}

// The same end for evaluate(): its columns as twists (v, ω, s), 7 doubles each, as a tree end's
// (add_twist_columns). ∂R(u)/∂u_k = ([ω_k]× + s_k) R(u) with ω_k = 2 G(u) e_k / |u|² and
// s_k = 2 u_k / |u|² (a ball joint's axes, src/tree/tree.cpp place_ball), so the frame moves by
// ∂R = ([ω_k]× + s_k) R and ∂p = ω_k × (p − x) + s_k (p − x); x_c moves it by v = e_c.
// `weld`: for weld_twist_rows, which reads neither ṗ nor the columns of x (End::unit_columns):
// they are not written.
void free_body_twists(const End& e, CVecRef q, CVecRef qd, FrameState& s, double* twists,
                      bool weld = false) {
  double x[7];
  const Eigen::Vector3d rv = free_body_pose(e, q, qd, s, x, !weld);
  const double w = x[3], a = x[4], b = x[5], c = x[6];
  const double qs = 2.0 / (w * w + a * a + b * b + c * c);
  const double r[3] = {rv(0), rv(1), rv(2)};
  for (int k = 0; k < 3 && !weld; ++k) {
    double* t = twists + 7 * k;
    for (int i = 0; i < 7; ++i) t[i] = i == k ? 1.0 : 0.0;
  }
  // 2 G(u) = 2 [−x w −z y; −y z w −x; −z −y x w] (its columns e_k's ω up to 1/|u|²), and s_k:
  // every entry is ± one of qs·(w, x, y, z).
  const double sw = qs * w, sa = qs * a, sb = qs * b, sc = qs * c;
  const auto twist = [&r](double* t, double o0, double o1, double o2, double sk) {  // ω × r + s r
    t[0] = (o1 * r[2] - o2 * r[1]) + sk * r[0];
    t[1] = (o2 * r[0] - o0 * r[2]) + sk * r[1];
    t[2] = (o0 * r[1] - o1 * r[0]) + sk * r[2];
    t[3] = o0;
    t[4] = o1;
    t[5] = o2;
    t[6] = sk;
  };
  twist(twists + 21, -sa, -sb, -sc, sw);
  twist(twists + 28, sw, sc, -sb, sa);
  twist(twists + 35, -sc, sw, sa, sb);
  twist(twists + 42, sb, -sa, sw, sc);
}

End make_end(NumericFrameEnd e, const std::vector<std::string>& coords, SymbolTable& table,
             const std::string& frame) {
  End end;
  end.spec = std::move(e);
  end.n_system = static_cast<Index>(coords.size());
  const NumericFrameEnd& s = end.spec;
  if (s.kind == NumericFrameEnd::Kind::tree) {
    for (Index j = 0; j < s.tree->dof(); ++j) end.cols.push_back(s.first_coordinate + j);
    end.scratch = s.tree->slot_size();
    const auto& links = s.tree->model().links;
    end.scale = std::any_of(links.begin(), links.end(), [](const tree::Link& l) {
      return l.type == tree::JointType::ball || l.type == tree::JointType::floating;
    });
  } else if (s.kind == NumericFrameEnd::Kind::expressions) {
    const InputMap in = coordinate_inputs(table, coords, InputSet::q_qd_time);
    std::vector<ex> x;
    for (const ex& v : s.pose.position) x.push_back(v);
    for (const ex& v : s.pose.rotation) x.push_back(v);
    const GiNaC::symbol t = time_symbol(table);
    for (const ex& v : x) {
      if (v.has(t)) throw DefinitionError("frame '" + frame + "' moves with t: not supported here");
    }
    std::vector<GiNaC::symbol> q, qd;
    for (std::size_t j = 0; j < coords.size(); ++j) {
      const GiNaC::symbol qj = coordinate_symbol(table, coords[j]);
      if (std::any_of(x.begin(), x.end(), [&](const ex& v) { return v.has(qj); })) {
        end.cols.push_back(static_cast<Index>(j));
        q.push_back(qj);
        qd.push_back(velocity_symbol(table, coords[j]));
      }
    }
    std::vector<ex> out = x;
    std::vector<std::vector<ex>> dx(q.size());
    for (std::size_t c = 0; c < q.size(); ++c) {
      for (const ex& v : x) dx[c].push_back(v.diff(q[c]));
      out.insert(out.end(), dx[c].begin(), dx[c].end());
    }
    // ẍ|q̈=0 = Σ_c (Σ_d ∂²x/∂q_c∂q_d q̇_d) q̇_c.
    for (std::size_t i = 0; i < x.size(); ++i) {
      ex acc = 0;
      for (std::size_t c = 0; c < q.size(); ++c) {
        ex rate = 0;
        for (std::size_t d = 0; d < q.size(); ++d) rate += dx[c][i].diff(q[d]) * qd[d];
        acc += rate * qd[c];
      }
      out.push_back(acc.expand());
    }
    end.tape = Tape(out, in);
    end.scratch = static_cast<Index>(end.tape.work_size() + end.tape.outputs());
    free_body_frame(end, q, x);
  }
  end.consecutive = true;
  for (std::size_t c = 1; c < end.cols.size(); ++c)
    end.consecutive = end.consecutive && end.cols[c] == end.cols[0] + static_cast<Index>(c);
  return end;
}

// The ends' state at (q, q̇), with `scratch` (End::scratch doubles) for the tree or the tape.
// scratch: e.scratch doubles, or (scratch_size) fewer for a tree end, which then evaluates in a
// workspace of its own (TreeSubsystem::frame_state without a slot).
void end_state(const End& e, CVecRef q, CVecRef qd, double* scratch, FrameState& s,
               Index scratch_size = -1) {
  const NumericFrameEnd& spec = e.spec;
  switch (spec.kind) {
    case NumericFrameEnd::Kind::fixed:
      s.p = spec.offset_p;
      s.R = spec.offset_R;
      s.pd.setZero();
      s.pdd.setZero();
      s.Rd.setZero();
      s.Rdd.setZero();
      return;
    case NumericFrameEnd::Kind::tree: {
      const Index n = spec.tree->dof();
      spec.tree->frame_state(
          q.segment(spec.first_coordinate, n), qd.segment(spec.first_coordinate, n), spec.link,
          spec.offset_R, spec.offset_p,
          Slot(scratch, static_cast<std::size_t>(scratch_size < 0 ? e.scratch : scratch_size)), s);
      return;
    }
    case NumericFrameEnd::Kind::expressions: {
      if (e.free_body) {
        free_body_state(e, q, qd, s);
        return;
      }
      double* out = scratch + e.tape.work_size();
      e.tape.eval(0.0, q.data(), qd.data(), out, scratch);
      const auto nc = static_cast<Index>(e.cols.size());
      for (int i = 0; i < 3; ++i) s.p(i) = out[i];
      for (int i = 0; i < 9; ++i) s.R(i / 3, i % 3) = out[3 + i];
      s.pd.setZero();
      s.Rd.setZero();
      for (Index c = 0; c < nc; ++c) {
        const double* d = out + 12 * (c + 1);
        const double v = qd(e.cols[static_cast<std::size_t>(c)]);
        for (int i = 0; i < 3; ++i) s.dp(i, c) = d[i];
        for (int i = 0; i < 9; ++i) s.dR(i, c) = d[3 + i];
        for (int i = 0; i < 3; ++i) s.pd(i) += d[i] * v;
        for (int i = 0; i < 9; ++i) s.Rd(i / 3, i % 3) += d[3 + i] * v;
      }
      const double* acc = out + 12 * (nc + 1);
      for (int i = 0; i < 3; ++i) s.pdd(i) = acc[i];
      for (int i = 0; i < 9; ++i) s.Rdd(i / 3, i % 3) = acc[3 + i];
      return;
    }
  }
}

// G (m × 6) of one end: [∂Φ/∂p, Σ_rc ∂Φ/∂R_rc ([e_k]× R)_rc].
void twist_map(const RowValues<double>& r, const Eigen::Matrix3d& R, int p0, int r0, MatRef G) {
  for (int i = 0; i < r.m; ++i) {
    for (int k = 0; k < 3; ++k) G(i, k) = r.D(i, p0 + k);
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector3d e = Eigen::Vector3d::Zero();
      e(k) = 1.0;
      Eigen::Matrix3d E;
      E << 0.0, -e.z(), e.y(), e.z(), 0.0, -e.x(), -e.y(), e.x(), 0.0;
      const Eigen::Matrix3d ER = E * R;
      double s = 0.0;
      for (int c = 0; c < 9; ++c) s += r.D(i, r0 + c) * ER(c / 3, c % 3);
      G(i, 3 + k) = s;
    }
  }
}

// [v; ω] = J q̇ of one end over all n coordinates: ω from ∂R/∂q_c Rᵀ = [ω_c]×.
void twist_jacobian(const FrameState& s, const std::vector<Index>& cols, Index n, Mat& J) {
  J.setZero(6, n);
  for (std::size_t c = 0; c < cols.size(); ++c) {
    const auto ci = static_cast<Index>(c);
    Eigen::Matrix3d dR;
    for (int i = 0; i < 9; ++i) dR(i / 3, i % 3) = s.dR(i, ci);
    const Eigen::Matrix3d W = dR * s.R.transpose();
    J.block<3, 1>(0, cols[c]) = s.dp.col(ci);
    J(3, cols[c]) = W(2, 1);
    J(4, cols[c]) = W(0, 2);
    J(5, cols[c]) = W(1, 0);
  }
}

// A(:, cols) += D_end ∂x_end/∂q over one end's columns.
// Each column summed in a local array down D's columns (contiguous; MR > 0: the rows known at
// compile time, the loops unroll), the same terms in the same order as one row at a time.
template <int MR>
void add_columns_m(const FrameState& s, const std::vector<Index>& cols, const RowValues<double>& r,
                   int p0, int r0, MatRef A) {
  const int m = MR > 0 ? MR : r.m;
  for (std::size_t c = 0; c < cols.size(); ++c) {
    const auto ci = static_cast<Index>(c);
    double v[kMaxRows] = {};
    for (int k = 0; k < 3; ++k) {
      const double x = s.dp(k, ci);
      for (int i = 0; i < m; ++i) v[i] += r.D(i, p0 + k) * x;
    }
    for (int k = 0; k < 9; ++k) {
      const double x = s.dR(k, ci);
      for (int i = 0; i < m; ++i) v[i] += r.D(i, r0 + k) * x;
    }
    for (int i = 0; i < m; ++i) A(i, cols[c]) += v[i];
  }
}
void add_columns(const FrameState& s, const std::vector<Index>& cols, const RowValues<double>& r,
                 int p0, int r0, MatRef A) {
  if (r.m == kMaxRows) {
    add_columns_m<kMaxRows>(s, cols, r, p0, r0, A);
  } else {
    add_columns_m<0>(s, cols, r, p0, r0, A);
  }
}

// An end's state for evaluate(): a tree end by frame_twists (its columns as twists (v, ω, s),
// 7 per coordinate, in `twists`; the link placements its subsystem's dynamics() left in its slot
// reused when they are of this state), a free-body end by free_body_twists (twists too; `weld`:
// what weld_twist_rows reads of it), any other end by end_state (dp, dR).
void end_twists(const End& e, const ConstraintSlots& slots, CVecRef q, CVecRef qd, double* scratch,
                FrameState& s, double* twists, bool weld = false) {
  const NumericFrameEnd& spec = e.spec;
  if (e.free_body) {
    free_body_twists(e, q, qd, s, twists, weld);
    return;
  }
  if (spec.kind != NumericFrameEnd::Kind::tree) {
    end_state(e, q, qd, scratch, s);
    return;
  }
  const Index n = spec.tree->dof(), c0 = spec.first_coordinate;
  spec.tree->frame_twists(q.segment(c0, n), qd.segment(c0, n), spec.link, spec.offset_R,
                          spec.offset_p, slots.subsystem(c0),
                          Slot(scratch, static_cast<std::size_t>(e.scratch)), s, twists);
}

// A(:, cols[c]) += G t_c (m rows, MR > 0: known at compile time), each column summed in a local
// array down G's columns, the same terms in the same order as one row at a time. The first np rows
// are an end's position alone (position_rows: G(i, :) = ±e_iᵀ, so G t_c is ±t_c(i), its only
// non-zero term) and the rows after them do not read the positions (weld_row, hinge_row: G's
// columns 0–2 are 0 there, so their sums start at column k0 = 3); np = 0: every row in full.
template <int MR, int NP>
void add_map_columns(const Eigen::Matrix<double, kMaxRows, 7>& G, const std::vector<Index>& cols,
                     const double* twists, int m_rt, int np_rt, MatRef A) {
  const int m = MR > 0 ? MR : m_rt, np = MR > 0 ? NP : np_rt, k0 = np > 0 ? 3 : 0;
  if constexpr (MR > 0) {  // fixed-size vectors of MR − NP rows: the same sums, vectorised
    constexpr int MO = MR - NP;
    for (std::size_t c = 0; c < cols.size(); ++c) {
      const double* t = twists + 7 * c;
      Eigen::Matrix<double, MO, 1> v = G.col(k0).template segment<MO>(NP) * t[k0];
      for (int k = k0 + 1; k < 7; ++k) v += G.col(k).template segment<MO>(NP) * t[k];
      for (int i = 0; i < NP; ++i) A(i, cols[c]) += G(i, i) * t[i];
      A.col(cols[c]).template segment<MO>(NP) += v;
    }
    return;
  }
  for (std::size_t c = 0; c < cols.size(); ++c) {
    const double* t = twists + 7 * c;
    double v[kMaxRows] = {};
    for (int i = 0; i < np; ++i) v[i] = G(i, i) * t[i];
    for (int k = k0; k < 7; ++k)
      for (int i = np; i < m; ++i) v[i] += G(i, k) * t[k];
    for (int i = 0; i < m; ++i) A(i, cols[c]) += v[i];
  }
}

// A(:, cols) += G t_c over a tree end's twist columns t_c = (v, ω, s): with ∂p = v and
// ∂R = ([ω]× + s) R, D ∂x = D_p v + Σ_c D_R(:, c) · (ω × R_c + s R_c), so G = [D_p, Σ_c R_c × d_c,
// Σ_c R_c · d_c] per row (d_c: the row's ∂Φ/∂R(:, c), R_c: R's column c). np: the leading position
// rows of add_map_columns, whose G is ±e_iᵀ (only their diagonal is formed).
// G(i, 3..6) = (Σ_c R_c × d_c, Σ_c R_c · d_c) of one row, d_c its ∂Φ/∂R(:, c), c in order.
void rotation_map_row(const Eigen::Matrix3d& R, const Eigen::Vector3d (&d)[3],
                      Eigen::Matrix<double, kMaxRows, 7>& G, int i) {
  Eigen::Vector3d w = Eigen::Vector3d::Zero();
  double sc = 0.0;
  for (int c = 0; c < 3; ++c) {
    w += R.col(c).cross(d[c]);
    sc += R.col(c).dot(d[c]);
  }
  for (int k = 0; k < 3; ++k) G(i, 3 + k) = w(k);
  G(i, 6) = sc;
}

void add_twist_columns(const FrameState& s, const std::vector<Index>& cols, const double* twists,
                       const RowValues<double>& r, int p0, int r0, int np, MatRef A) {
  Eigen::Matrix<double, kMaxRows, 7> G;
  for (int i = 0; i < np; ++i) G(i, i) = r.D(i, p0 + i);
  for (int i = np; i < r.m; ++i) {
    Eigen::Vector3d d[3];
    for (int c = 0; c < 3; ++c) d[c] = {r.D(i, r0 + c), r.D(i, r0 + 3 + c), r.D(i, r0 + 6 + c)};
    rotation_map_row(s.R, d, G, i);
    for (int k = 0; k < 3; ++k) G(i, k) = r.D(i, p0 + k);
  }
  if (r.m == kMaxRows && np == 3) {
    add_map_columns<kMaxRows, 3>(G, cols, twists, r.m, np, A);
  } else if (r.m == kMaxRows && np == 0) {
    add_map_columns<kMaxRows, 0>(G, cols, twists, r.m, np, A);
  } else {
    add_map_columns<0, 0>(G, cols, twists, r.m, np, A);
  }
}

// One end's columns of a weld's A (weld_twist_rows), its G given as W (G's columns 3–5 of the
// orientation rows) and g (column 6): A(0:3, c) = ±t_c(0:3) (the position rows, G = ±e_iᵀ; NEG:
// −) and A(3:6, c) = W ω_c + g s_c, the terms in add_map_columns' order (ω's three, then s's).
// The end's first unit_columns (0 or 3) are a free body's translations (t_c = e_c: ±e_c and
// zeros, no products); its columns are consecutive (End::consecutive); without End::scale (a tree of revolute and prismatic joints: every s_c is an exact
// zero) the term g s_c is left out. SET: the columns are set, else added to. Two columns at a
// time, one in each lane of a 2-vector (the same sums per column), W and g in locals: no reload
// per column.
template <bool SCALE, bool SET, bool NEG>
void weld_end_columns(const End& e, const double* twists, const double (&W)[3][3],
                      const double (&g)[3], MatRef A) {
  using P = Eigen::Array2d;
  const Index ld = A.outerStride();
  const auto put = [](double& x, double v) { x = SET ? v : x + v; };
  const auto unit = static_cast<std::size_t>(e.unit_columns), n = e.cols.size();
  if (n == 0) return;
  double* const A0 = A.data() + ld * e.cols[0];  // column c of the end at A0 + ld c
  constexpr double one = NEG ? -1.0 : 1.0, zero = NEG ? -0.0 : 0.0;  // ±1 · (1, 0)
  if (unit == 3) {
    for (std::size_t c = 0; c < 3; ++c) {
      double* a = A0 + ld * static_cast<Index>(c);
      put(a[0], c == 0 ? one : zero);
      put(a[1], c == 1 ? one : zero);
      put(a[2], c == 2 ? one : zero);
      if constexpr (SET) a[3] = a[4] = a[5] = 0.0;
    }
  }
  P w[3][3], gs[3];
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) w[r][k] = P::Constant(W[r][k]);
    gs[r] = P::Constant(g[r]);
  }
  // Rows 3–5 of columns c and c + 1 (a second copy of c past the last).
  const auto rows = [&](std::size_t c, bool two, P(&v)[3]) {
    const double* t = twists + 7 * c;
    const double* u = two ? t + 7 : t;
    const P t3(t[3], u[3]), t4(t[4], u[4]), t5(t[5], u[5]);
    for (int r = 0; r < 3; ++r) {
      v[r] = w[r][0] * t3 + w[r][1] * t4 + w[r][2] * t5;
      if constexpr (SCALE) v[r] += gs[r] * P(t[6], u[6]);
    }
  };
  const auto column = [&](std::size_t c, const P(&v)[3], int h) {
    const double* t = twists + 7 * c;
    double* a = A0 + ld * static_cast<Index>(c);
    const P p = Eigen::Map<const P>(t);
    Eigen::Map<P> ap(a);
    if constexpr (SET) {
      ap = NEG ? P(-p) : p;
    } else {
      ap += NEG ? P(-p) : p;
    }
    put(a[2], NEG ? -t[2] : t[2]);
    for (int r = 0; r < 3; ++r) put(a[3 + r], v[r](h));
  };
  std::size_t c = unit;
  for (; c + 1 < n; c += 2) {
    P v[3];
    rows(c, true, v);
    column(c, v, 0);
    column(c + 1, v, 1);
  }
  if (c < n) {
    P v[3];
    rows(c, false, v);
    column(c, v, 0);
  }
}

template <bool SET, bool NEG>
void weld_end_columns(const End& e, const double* twists, const double (&W)[3][3],
                      const double (&g)[3], MatRef A) {
  if (e.scale) {
    weld_end_columns<true, SET, NEG>(e, twists, W, g, A);
  } else {
    weld_end_columns<false, SET, NEG>(e, twists, W, g, A);
  }
}

// x·y of 3-vectors, summed as Eigen sums a Vector3d's dot: (x0 y0 + x1 y1) + x2 y2.
inline double dot3(const double* x, const double* y) {
  return x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
}

// x × y − z × v of 3-vectors into out (each cross product as Eigen's, then subtracted).
inline void cross_difference(const double* x, const double* y, const double* z, const double* v,
                             double* out) {
  out[0] = (x[1] * y[2] - x[2] * y[1]) - (z[1] * v[2] - z[2] * v[1]);
  out[1] = (x[2] * y[0] - x[0] * y[2]) - (z[2] * v[0] - z[0] * v[2]);
  out[2] = (x[0] * y[1] - x[1] * y[0]) - (z[0] * v[1] - z[1] * v[0]);
}

// weld_twist_rows' orientation row w = (i, j) (the 3 − i − j of (2, 1), (0, 2), (1, 0)): W's row
// w, g(w) and b(3 + w), the indices known at compile time (constant offsets into R, Ṙ, R̈).
template <int W, int I, int J>
void weld_orientation_row(const FrameState& a, const FrameState& b, double (&Wm)[3][3],
                          double (&g)[3], double (&bo)[6]) {
  const double *ai = a.R.data() + 3 * I, *aj = a.R.data() + 3 * J;
  const double *bi = b.R.data() + 3 * I, *bj = b.R.data() + 3 * J;
  double c[3];
  cross_difference(ai, bj, aj, bi, c);
  for (int k = 0; k < 3; ++k) Wm[W][k] = 0.5 * c[k];
  g[W] = 0.5 * (dot3(ai, bj) - dot3(aj, bi));
  const double dx = 0.5 * (((dot3(bj, a.Rdd.data() + 3 * I) - dot3(bi, a.Rdd.data() + 3 * J)) +
                            dot3(ai, b.Rdd.data() + 3 * J)) -
                           dot3(aj, b.Rdd.data() + 3 * I));
  const double hx = dot3(a.Rd.data() + 3 * I, b.Rd.data() + 3 * J) -
                    dot3(a.Rd.data() + 3 * J, b.Rd.data() + 3 * I);
  bo[3 + W] = -(dx + hx);
}

// A weld between two twist ends (a tree's or a free body's) for evaluate(), without forming
// RowValues' D (144 entries, mostly zeros) and its product with the 24 rates: its rows are
// position_rows (G = ±e_iᵀ on p_a, p_b) and weld_row (i, j) for (2, 1), (0, 2), (1, 0), whose
// ∂Φ/∂R_a has the columns d_i = ½ R_b(:, j), d_j = −½ R_b(:, i) and ∂Φ/∂R_b the columns
// d_j = ½ R_a(:, i), d_i = −½ R_a(:, j) (the values weld_row writes into D). G's orientation
// rows by rotation_map_row's sums without its column of zeros: end a's (w, g) with
// w = R_a(:, i) × d_i + R_a(:, j) × d_j, g = R_a(:, i)·d_i + R_a(:, j)·d_j, and end b's (−w, g)
// exactly (each cross product of b's is one of a's with its factors swapped, each dot product one
// of a's with its factors swapped), so A is add_twist_columns' bit for bit. b = −(D ẍ + ẋᵀHẋ)
// on the same non-zero terms. The ½ is taken out of each sum (w = ½ (R_a(:, i) × R_b(:, j) −
// R_a(:, j) × R_b(:, i)), …): a power of two, so the same bits as the terms scaled one by one.
// On raw doubles (R's column k at R.data() + 3 k). End a's columns of A are set; `disjoint` (the
// ends have no column in common): b's are set too, else added onto a's.
void weld_twist_rows(const FrameState& a, const FrameState& b, const End& ea, const double* ta,
                     const End& eb, const double* tb, bool disjoint, MatRef A, VecRef bv) {
  double Wa[3][3], Wb[3][3], g[3], bo[6];
  for (int k = 0; k < 3; ++k) bo[k] = -(a.pdd(k) - b.pdd(k));
  weld_orientation_row<0, 2, 1>(a, b, Wa, g, bo);
  weld_orientation_row<1, 0, 2>(a, b, Wa, g, bo);
  weld_orientation_row<2, 1, 0>(a, b, Wa, g, bo);
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) Wb[r][k] = -Wa[r][k];
  for (int k = 0; k < 6; ++k) bv(k) = bo[k];
  weld_end_columns<true, false>(ea, ta, Wa, g, A);
  if (disjoint) {
    weld_end_columns<true, true>(eb, tb, Wb, g, A);
  } else {
    weld_end_columns<false, true>(eb, tb, Wb, g, A);
  }
}

// ---------------------------------------------------------------- derivatives (dual numbers)

// One tangent direction: value and directional derivative (tree/dual.hpp).
using ukdyn::detail::Dual;
using ukdyn::detail::dual;
using ukdyn::detail::tangent_of;
using DV3 = Eigen::Matrix<Dual, 3, 1>;
using DM3 = Eigen::Matrix<Dual, 3, 3>;

// A frame's state on dual numbers along one direction (dq, dq̇) at fixed q̈: pdd, Rdd are the
// acceleration AT q̈ (so that A q̈ − b = D ẍ + ẋᵀHẋ). The columns dp, dR of its end are kept as
// values and tangents in two FrameStates (in the constraint's slot: no allocation per direction).
template <class D>
struct LaneFrame {
  Eigen::Matrix<D, 3, 1> p, pd, pdd;
  Eigen::Matrix<D, 3, 3> R, Rd, Rdd;
};
using DualFrame = LaneFrame<Dual>;

template <class M, class DM>
void combine(const M& value, const M& tangent, DM& out) {
  for (Index i = 0; i < value.rows(); ++i)
    for (Index j = 0; j < value.cols(); ++j) out(i, j) = dual(value(i, j), tangent(i, j));
}

void combine(const FrameState& v, const FrameState& t, DualFrame& s) {
  combine(v.p, t.p, s.p);
  combine(v.R, t.R, s.R);
  combine(v.pd, t.pd, s.pd);
  combine(v.Rd, t.Rd, s.Rd);
  combine(v.pdd, t.pdd, s.pdd);
  combine(v.Rdd, t.Rdd, s.Rdd);
}

// An end's room in the slot: its scratch (End::scratch: the tree's workspace, or the tape's work
// and outputs) and, for an expressions end, as much again for the tape's tangents.
struct EndScratch {
  double* scratch;
  double* room;
};

Index tangent_room(const End& e) {
  return e.spec.kind == NumericFrameEnd::Kind::expressions ? e.scratch : 0;
}

// ------------------------------------------------ every direction at once (lanes)

// Several directions per pass (vector-mode forward differentiation, Griewank & Walther 2008,
// §3.1): one lane per direction, as the tree's frame_state_jacobian() runs them.
constexpr int kLanes = 8;
using Lanes = LaneDual<kLanes>;

// Directions per pass of an expressions end's tape (Tape::eval_tangents) in its J.
std::size_t tape_lanes(const End& e) {
  return std::min<std::size_t>(symbolic::kTapeLanes, 2 * e.cols.size());
}

// A tree end's frame_state_jacobian() in the slot: (36 + 12 nc) × 2 nc doubles.
// An expressions end's: the same J, then its tape's tangents on tape_lanes() lanes: the lanes'
// directions (n_system × lanes for q and for q̇), the work's and the outputs' tangents.
Index lane_room(const End& e) {
  const auto nc = static_cast<Index>(e.cols.size());
  if (e.spec.kind == NumericFrameEnd::Kind::fixed) return 0;
  const Index J = (36 + 12 * nc) * 2 * nc;
  if (e.spec.kind == NumericFrameEnd::Kind::tree) return J;
  const auto lanes = static_cast<Index>(tape_lanes(e));
  return J + lanes * (2 * e.n_system + static_cast<Index>(e.tape.work_size() + e.tape.outputs()));
}

// One end in a pass: its state (values v), its frame_state_jacobian() J (ld rows; null: a fixed
// end) and, per lane, the column of J of the lane's direction (−1: it does not move the end).
struct LaneEnd {
  const FrameState* v;
  const double* J;
  Index ld;
  Index col[kLanes];
};

template <int R, int C>
void lift(const Eigen::Matrix<double, R, C>& v, Index row, const LaneEnd& e,
          Eigen::Matrix<Lanes, R, C>& out) {
  for (Index r = 0; r < R * C; ++r) {
    Lanes x(v(r / C, r % C));
    for (int l = 0; l < kLanes; ++l) {
      if (e.col[l] >= 0) x.d[l] = e.J[row + r + e.col[l] * e.ld];
    }
    out(r / C, r % C) = x;
  }
}

void lift(const LaneEnd& e, LaneFrame<Lanes>& s) {
  lift(e.v->p, 0, e, s.p);
  lift(e.v->R, 3, e, s.R);
  lift(e.v->pd, 12, e, s.pd);
  lift(e.v->Rd, 15, e, s.Rd);
  lift(e.v->pdd, 24, e, s.pdd);
  lift(e.v->Rdd, 27, e, s.Rdd);
}

// d_force(cols, out_col[l]) += lane l of d(J_endᵀ D_endᵀ λ) (add_force_tangent on lanes).
void add_force_lanes(const LaneEnd& e, const std::vector<Index>& cols, const RowValues<Lanes>& r,
                     int p0, int r0, CVecRef lambda, const Index* out_col, int lanes,
                     MatRef d_force) {
  Eigen::Matrix<Lanes, 12, 1> g;
  for (int k = 0; k < 12; ++k) {
    g(k) = Lanes(0.0);
    const int col = k < 3 ? p0 + k : r0 + (k - 3);
    for (int i = 0; i < r.m; ++i) g(k) += r.D(i, col) * lambda(i);
  }
  for (std::size_t c = 0; c < cols.size(); ++c) {
    const auto ci = static_cast<Index>(c);
    for (int l = 0; l < lanes; ++l) {
      double f = 0.0;
      for (int k = 0; k < 12; ++k) {
        const double x = k < 3 ? e.v->dp(k, ci) : e.v->dR(k - 3, ci);
        f += g(k).d[l] * x;
        if (e.col[l] >= 0) f += g(k).value() * e.J[36 + 12 * ci + k + e.col[l] * e.ld];
      }
      d_force(cols[c], out_col[l]) += f;
    }
  }
}

// A tree end: frame_state_tangent (the recursive pass on dual numbers).
void tree_end_tangent(const End& e, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef dq, CVecRef dqd,
                      double* scratch, FrameState& v, FrameState& t, DualFrame& s) {
  const NumericFrameEnd& spec = e.spec;
  const Index n = spec.tree->dof(), c0 = spec.first_coordinate;
  spec.tree->frame_state_tangent(q.segment(c0, n), qd.segment(c0, n), qdd.segment(c0, n),
                                 dq.segment(c0, n), dqd.segment(c0, n), spec.link, spec.offset_R,
                                 spec.offset_p, Slot(scratch, static_cast<std::size_t>(e.scratch)),
                                 v, t);
  combine(v, t, s);
}

// An expressions end: its tape (x, ∂x/∂q_c, ẍ|q̈=0) along the direction (Tape::eval_tangent),
// then ẋ = Σ_c ∂x/∂q_c q̇_c and ẍ = ẍ|q̈=0 + Σ_c ∂x/∂q_c q̈_c on dual numbers. scratch: out, work
// (End::scratch), then dwork, dout in `room` (as many).
void expression_end_tangent(const End& e, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef dq,
                            CVecRef dqd, EndScratch x, FrameState& v, FrameState& t, DualFrame& s) {
  const std::size_t nw = e.tape.work_size();
  double* work = x.scratch;
  double* out = x.scratch + nw;
  double* dwork = x.room;
  double* dout = x.room + nw;
  e.tape.eval_tangent(0.0, q.data(), qd.data(), 0.0, dq.data(), dqd.data(), out, dout, work, dwork);
  auto at = [&](std::size_t i) { return dual(out[i], dout[i]); };
  const auto nc = static_cast<Index>(e.cols.size());
  for (int i = 0; i < 3; ++i) s.p(i) = at(static_cast<std::size_t>(i));
  for (int i = 0; i < 9; ++i) s.R(i / 3, i % 3) = at(static_cast<std::size_t>(3 + i));
  const std::size_t acc = 12 * static_cast<std::size_t>(nc + 1);
  for (int i = 0; i < 3; ++i) s.pdd(i) = at(acc + static_cast<std::size_t>(i));
  for (int i = 0; i < 9; ++i) s.Rdd(i / 3, i % 3) = at(acc + 3 + static_cast<std::size_t>(i));
  s.pd.setZero();
  s.Rd.setZero();
  for (Index c = 0; c < nc; ++c) {
    const std::size_t d = 12 * static_cast<std::size_t>(c + 1);
    const Index col = e.cols[static_cast<std::size_t>(c)];
    const Dual w = dual(qd(col), dqd(col));
    const double a = qdd(col);
    for (int i = 0; i < 3; ++i) {
      const Dual dp = at(d + static_cast<std::size_t>(i));
      v.dp(i, c) = out[d + static_cast<std::size_t>(i)];
      t.dp(i, c) = dout[d + static_cast<std::size_t>(i)];
      s.pd(i) += dp * w;
      s.pdd(i) += dp * a;
    }
    for (int i = 0; i < 9; ++i) {
      const Dual dR = at(d + 3 + static_cast<std::size_t>(i));
      v.dR(i, c) = out[d + 3 + static_cast<std::size_t>(i)];
      t.dR(i, c) = dout[d + 3 + static_cast<std::size_t>(i)];
      s.Rd(i / 3, i % 3) += dR * w;
      s.Rdd(i / 3, i % 3) += dR * a;
    }
  }
}

// An end the direction does not move (its coordinates' dq, dq̇ all zero): its state in doubles
// (end_state) with zero tangents, the acceleration at q̈ = ẍ|q̈=0 + Σ_c ∂x/∂q_c q̈_c.
void still_end(const End& e, CVecRef q, CVecRef qd, CVecRef qdd, double* scratch, FrameState& v,
               FrameState& t, DualFrame& s) {
  end_state(e, q, qd, scratch, v);
  for (std::size_t c = 0; c < e.cols.size(); ++c) {
    const auto ci = static_cast<Index>(c);
    const double a = qdd(e.cols[c]);
    v.pdd += v.dp.col(ci) * a;
    for (int i = 0; i < 9; ++i) v.Rdd(i / 3, i % 3) += v.dR(i, ci) * a;
  }
  t.p.setZero();
  t.R.setZero();
  t.pd.setZero();
  t.Rd.setZero();
  t.pdd.setZero();
  t.Rdd.setZero();
  t.dp.setZero();
  t.dR.setZero();
  combine(v, t, s);
}

bool moves(const End& e, CVecRef dq, CVecRef dqd) {
  return std::any_of(e.cols.begin(), e.cols.end(),
                     [&](Index c) { return dq(c) != 0.0 || dqd(c) != 0.0; });
}

void end_tangent(const End& e, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef dq, CVecRef dqd,
                 EndScratch x, FrameState& v, FrameState& t, DualFrame& s) {
  if (e.spec.kind == NumericFrameEnd::Kind::fixed) {
    s.p = e.spec.offset_p.cast<Dual>();
    s.R = e.spec.offset_R.cast<Dual>();
    s.pd.setZero();
    s.pdd.setZero();
    s.Rd.setZero();
    s.Rdd.setZero();
  } else if (!moves(e, dq, dqd)) {
    still_end(e, q, qd, qdd, x.scratch, v, t, s);
  } else if (e.spec.kind == NumericFrameEnd::Kind::tree) {
    tree_end_tangent(e, q, qd, qdd, dq, dqd, x.scratch, v, t, s);
  } else {
    expression_end_tangent(e, q, qd, qdd, dq, dqd, x, v, t, s);
  }
}

// d_force(cols) += d(J_endᵀ D_endᵀ λ): the end's part of d(Aᵀλ), its columns ∂x/∂q_c as values v
// and tangents t. Dᵀλ over the end's 12 entries is formed once (g), then dotted with each column.
void add_force_tangent(const FrameState& v, const FrameState& t, const std::vector<Index>& cols,
                       const RowValues<Dual>& r, int p0, int r0, CVecRef lambda, VecRef d_force) {
  Eigen::Matrix<Dual, 12, 1> g;
  for (int k = 0; k < 12; ++k) {
    g(k) = Dual(0.0);
    const int col = k < 3 ? p0 + k : r0 + (k - 3);
    for (int i = 0; i < r.m; ++i) g(k) += r.D(i, col) * lambda(i);
  }
  for (std::size_t c = 0; c < cols.size(); ++c) {
    const auto ci = static_cast<Index>(c);
    double f = 0.0;  // the tangent of Σ_k g_k x_kc: Σ_k (dg_k x_kc + g_k dx_kc)
    for (int k = 0; k < 3; ++k) f += tangent_of(g(k)) * v.dp(k, ci) + g(k).value() * t.dp(k, ci);
    for (int k = 0; k < 9; ++k)
      f += tangent_of(g(3 + k)) * v.dR(k, ci) + g(3 + k).value() * t.dR(k, ci);
    d_force(cols[c]) += f;
  }
}

// Whether an end gives its columns as twists (end_twists: a tree or a free body).
bool twist_end(const End& e) { return e.spec.kind == NumericFrameEnd::Kind::tree || e.free_body; }

// A(:, cols) += D_end ∂x_end/∂q of an end as end_twists left it: twist columns of a tree or
// free-body end, dp and dR of any other.
void add_end_columns(const End& e, const FrameState& s, const double* twists,
                     const RowValues<double>& r, int p0, int r0, int np, MatRef A) {
  if (twist_end(e)) {
    add_twist_columns(s, e.cols, twists, r, p0, r0, np, A);
  } else {
    add_columns(s, e.cols, r, p0, r0, A);
  }
}

// ẋ and ẍ|q̈=0 of both ends as the 24-vectors of RowValues::D's columns.
Eigen::Matrix<double, 24, 1> rates(const FrameState& a, const FrameState& b, bool second);
// Row i of A q̈ − b = D ẍ + ẋᵀHẋ (ẍ: the frames' acceleration at q̈) on the scalar S.
template <class S>
S residual_row(const RowValues<S>& r, const LaneFrame<S>& a, const LaneFrame<S>& b, int i) {
  S res = r.Q(i);
  for (int k = 0; k < 3; ++k) res += r.D(i, kPa + k) * a.pdd(k) + r.D(i, kPb + k) * b.pdd(k);
  for (int k = 0; k < 9; ++k) {
    res += r.D(i, kRa + k) * a.Rdd(k / 3, k % 3) + r.D(i, kRb + k) * b.Rdd(k / 3, k % 3);
  }
  return res;
}

template <class M>
void put_tangents(const M& x, double* out) {
  for (Index r = 0; r < x.size(); ++r) out[r] = tangent_of(x(r / x.cols(), r % x.cols()));
}

// Column `col` of an expressions end's J (ld = 36 + 12 nc doubles at o) from its tape's outputs
// and their tangents along the column's direction (e_c of q, or of q̇ when col ≥ nc): what
// expression_end_tangent() gives on dual numbers, ẋ = Σ_c ∂x/∂q_c q̇_c and ẍ = ẍ|q̈=0 +
// Σ_c ∂x/∂q_c q̈_c differentiated term by term in the same order.
void expression_column(const End& e, const double* out, const double* dout, CVecRef qd, CVecRef qdd,
                       Index col, double* o) {
  const auto nc = static_cast<Index>(e.cols.size());
  const std::size_t acc = 12 * static_cast<std::size_t>(nc + 1);
  for (std::size_t i = 0; i < 12; ++i) {
    double rate = 0.0, accel = dout[acc + i];
    for (Index c = 0; c < nc; ++c) {
      const std::size_t d = 12 * static_cast<std::size_t>(c + 1) + i;
      const Index g = e.cols[static_cast<std::size_t>(c)];
      rate += dout[d] * qd(g) + out[d] * (col == nc + c ? 1.0 : 0.0);
      accel += dout[d] * qdd(g);
      o[36 + 12 * c + static_cast<Index>(i)] = dout[d];
    }
    // (p, R) at rows 0, 3; (ṗ, Ṙ) at 12, 15; (p̈, R̈) at 24, 27 (put_tangents' layout).
    const auto row = static_cast<Index>(i);
    o[row] = dout[i];
    o[12 + row] = rate;
    o[24 + row] = accel;
  }
}

// An expressions end's state in v from its tape's outputs (the values of expression_end_tangent).
void expression_values(const End& e, const double* out, CVecRef qd, CVecRef qdd, FrameState& v) {
  const auto nc = static_cast<Index>(e.cols.size());
  const std::size_t acc = 12 * static_cast<std::size_t>(nc + 1);
  for (int i = 0; i < 12; ++i) {
    const auto u = static_cast<std::size_t>(i);
    double x = out[u], rate = 0.0, accel = out[acc + u];
    for (Index c = 0; c < nc; ++c) {
      const double dx = out[12 * static_cast<std::size_t>(c + 1) + u];
      const Index g = e.cols[static_cast<std::size_t>(c)];
      rate += dx * qd(g);
      accel += dx * qdd(g);
      if (i < 3) {
        v.dp(i, c) = dx;
      } else {
        v.dR(i - 3, c) = dx;
      }
    }
    if (i < 3) {
      v.p(i) = x;
      v.pd(i) = rate;
      v.pdd(i) = accel;
    } else {
      v.R((i - 3) / 3, (i - 3) % 3) = x;
      v.Rd((i - 3) / 3, (i - 3) % 3) = rate;
      v.Rdd((i - 3) / 3, (i - 3) % 3) = accel;
    }
  }
}

// An expressions end's J as a tree's frame_state_jacobian() stacks it, from its tape's tangents
// along every direction of its coordinates, tape_lanes() of them per pass (Tape::eval_tangents:
// the values once per pass), and its state in v. x.scratch: the tape's work and outputs; the
// lanes' room (lane_room) follows J.
void expression_jacobian(const End& e, CVecRef q, CVecRef qd, CVecRef qdd, EndScratch x, double* J,
                         FrameState& v) {
  const auto nc = static_cast<Index>(e.cols.size());
  const Index ld = 36 + 12 * nc;
  const std::size_t nw = e.tape.work_size(), no = e.tape.outputs(), per_pass = tape_lanes(e);
  const auto n = static_cast<std::size_t>(e.n_system);
  double* work = x.scratch;
  double* out = x.scratch + nw;
  double* dq = J + ld * 2 * nc;
  double* dqd = dq + n * per_pass;
  double* dwork = dqd + n * per_pass;
  double* dout = dwork + nw * per_pass;
  // An end that no coordinate moves (a frame of the world, turned or offset) has no column.
  if (nc == 0) e.tape.eval(0.0, q.data(), qd.data(), out, work);
  // The tape reads the directions of its inputs alone, the end's coordinates (e.cols: every
  // coordinate its pose depends on): only those entries of each lane are zeroed, O(columns) in
  // place of O(n) per lane.
  for (std::size_t k = 0; k < per_pass; ++k) {
    for (const Index g : e.cols) {
      dq[static_cast<std::size_t>(g) + n * k] = 0.0;
      dqd[static_cast<std::size_t>(g) + n * k] = 0.0;
    }
  }
  auto unit = [&](Index col, std::size_t k) -> double& {
    const auto g = static_cast<std::size_t>(e.cols[static_cast<std::size_t>(col % nc)]);
    return (col < nc ? dq : dqd)[g + n * k];
  };
  for (Index first = 0; first < 2 * nc; first += static_cast<Index>(per_pass)) {
    const auto lanes = std::min(per_pass, static_cast<std::size_t>(2 * nc - first));
    for (std::size_t k = 0; k < lanes; ++k) unit(first + static_cast<Index>(k), k) = 1.0;
    e.tape.eval_tangents(lanes, 0.0, q.data(), qd.data(), nullptr, dq, n, dqd, n, out, dout, work,
                         dwork);
    for (std::size_t k = 0; k < lanes; ++k) {
      const Index col = first + static_cast<Index>(k);
      expression_column(e, out, dout + no * k, qd, qdd, col, J + col * ld);
      unit(col, k) = 0.0;
    }
  }
  expression_values(e, out, qd, qdd, v);
}

// A free-body end's J (free_body_frame) in closed form, what expression_jacobian() gives from its
// tape: with R(u) = B(u, u) (quaternion_bilinear), p = x + R(u) o and R = R(u) R_o,
//   Ṙ(u) = 2 B(u, u̇),   R̈(u) at q̈ = 2 B(u̇, u̇) + 2 B(u, ü),   ∂R(u)/∂u_k = 2 B(e_k, u),
// so along δu of q: δR(u) = 2 B(u, δu), δṘ(u) = 2 B(δu, u̇), δR̈(u) = 2 B(δu, ü), δ∂R(u)/∂u_k =
// 2 B(e_k, δu); along δu̇ of q̇: δṘ(u) = 2 B(u, δu̇), δR̈(u) = 4 B(u̇, δu̇); δx, δẋ move p, ṗ by
// themselves. The state in v with its acceleration at q̈ (as expression_values).
void free_body_jacobian(const End& e, CVecRef q, CVecRef qd, CVecRef qdd, double* J,
                        FrameState& v) {
  free_body_state(e, q, qd, v);
  double u[4], ud[4], udd[4];
  for (std::size_t c = 0; c < 7; ++c) {
    const double a = qdd(e.cols[c]);
    v.pdd += v.dp.col(static_cast<Index>(c)) * a;
    for (int i = 0; i < 9; ++i) v.Rdd(i / 3, i % 3) += v.dR(i, static_cast<Index>(c)) * a;
    if (c >= 3) {
      u[c - 3] = q(e.cols[c]);
      ud[c - 3] = qd(e.cols[c]);
      udd[c - 3] = a;
    }
  }
  const Index ld = 36 + 12 * 7;
  // Rows r.. of column o: the position part M o (3), then the rotation M R_o (9, row-major).
  const auto put = [&e](double* o, Index r, const Eigen::Matrix3d& M) {
    const Eigen::Vector3d x = M * e.fb_o;
    const Eigen::Matrix3d R = M * e.fb_Ro;
    for (int i = 0; i < 3; ++i) o[r + i] = x(i);
    for (int i = 0; i < 9; ++i) o[r + 3 + i] = R(i / 3, i % 3);
  };
  for (Index col = 0; col < 14; ++col) {
    double* o = J + col * ld;
    std::fill_n(o, ld, 0.0);
    const bool rate = col >= 7;
    const Index c = col % 7;
    double du[4] = {0.0, 0.0, 0.0, 0.0};
    if (c >= 3) du[c - 3] = 1.0;
    if (!rate) {
      put(o, 0, 2.0 * quaternion_bilinear(u, du));
      put(o, 12, 2.0 * quaternion_bilinear(du, ud));
      put(o, 24, 2.0 * quaternion_bilinear(du, udd));
      for (Index k = 0; k < 4 && c >= 3; ++k) {
        double ek[4] = {0.0, 0.0, 0.0, 0.0};
        ek[k] = 1.0;
        put(o, 36 + 12 * (3 + k), 2.0 * quaternion_bilinear(ek, du));
      }
    } else {
      put(o, 12, 2.0 * quaternion_bilinear(u, du));
      put(o, 24, 4.0 * quaternion_bilinear(ud, du));
    }
    if (c < 3) o[(rate ? 12 : 0) + c] += 1.0;
  }
}

// An end's state and its J (a tree's frame_state_jacobian(), an expressions end's tape tangents;
// none for a fixed end). x: its scratch (the tape's work and outputs of an expressions end).
// A tree end reads the links its subsystem's slot holds at this state (frame_state_jacobian).
LaneEnd lane_end(const End& e, const ConstraintSlots& slots, CVecRef q, CVecRef qd, CVecRef qdd,
                 EndScratch x, double* J, FrameState& v) {
  LaneEnd out{&v, nullptr, 36 + 12 * static_cast<Index>(e.cols.size()), {}};
  const NumericFrameEnd& spec = e.spec;
  if (spec.kind == NumericFrameEnd::Kind::fixed) {
    end_state(e, q, qd, x.scratch, v);
    return out;
  }
  if (spec.kind == NumericFrameEnd::Kind::expressions) {
    if (e.free_body) {
      free_body_jacobian(e, q, qd, qdd, J, v);
    } else {
      expression_jacobian(e, q, qd, qdd, x, J, v);
    }
    out.J = J;
    return out;
  }
  const Index n = spec.tree->dof(), c0 = spec.first_coordinate;
  Eigen::Map<Mat> Jm(J, out.ld, 2 * n);
  spec.tree->frame_state_jacobian(q.segment(c0, n), qd.segment(c0, n), qdd.segment(c0, n),
                                  spec.link, spec.offset_R, spec.offset_p, slots.subsystem(c0),
                                  Slot(x.scratch, static_cast<std::size_t>(e.scratch)), v, Jm);
  out.J = J;
  return out;
}

// The column of a tree end's J along coordinate g of q (of q̇ when `rate`); −1 when g does not
// move the end (not one of its coordinates, a fixed end, g < 0).
Index lane_column(const End& e, Index g, bool rate) {
  const auto it = std::lower_bound(e.cols.begin(), e.cols.end(), g);
  if (g < 0 || it == e.cols.end() || *it != g) return -1;
  return (rate ? static_cast<Index>(e.cols.size()) : 0) + static_cast<Index>(it - e.cols.begin());
}

// One pass: both ends on lanes, the rows on lanes, lane l's d(A q̈ − b) into column out_col[l]
// of d_residual and its d(Aᵀλ) added to that of d_force.
[[gnu::flatten]] void lane_pass(const NumericFrameSpec& f, const End& a, const End& b,
                                const LaneEnd& A, const LaneEnd& B, CVecRef lambda,
                                const Index* out_col, int lanes, MatRef d_residual,
                                MatRef d_force) {
  LaneFrame<Lanes> sa, sb;
  lift(A, sa);
  lift(B, sb);
  RowValues<Lanes> r;
  row_values(f, sa, sb, r);
  for (int i = 0; i < r.m; ++i) {
    const Lanes res = residual_row(r, sa, sb, i);
    for (int l = 0; l < lanes; ++l) d_residual(i, out_col[l]) = res.d[l];
  }
  add_force_lanes(A, a.cols, r, kPa, kRa, lambda, out_col, lanes, d_force);
  add_force_lanes(B, b.cols, r, kPb, kRb, lambda, out_col, lanes, d_force);
}

// ------------------------------------------------ every direction at once (doubles)

// One nonzero of a row's Hessian H_i = ∂²Φ_i/∂x² (x = (p_a, R_a, p_b, R_b), RowValues::D's
// columns): ∂D(row, col)/∂x_wrt = h. Every row is at most bilinear in x (the header's comment), so
// H_i is constant, D_i(x) = ∂Φ_i/∂x is affine and Q_i = ẋᵀ H_i ẋ.
struct HessianEntry {
  int row, col, wrt;
  double h;
};

// The rows' Hessians, read once off D's tangents along the 24 entries of x (row_values on lanes,
// three passes of eight, at x = 0 with zero rates: D is affine in x, so its tangents are H exactly).
std::vector<HessianEntry> row_hessians(const NumericFrameSpec& f) {
  std::vector<HessianEntry> out;
  for (int j0 = 0; j0 < 24; j0 += kLanes) {
    LaneFrame<Lanes> a, b;
    for (LaneFrame<Lanes>* s : {&a, &b}) {
      s->p.setConstant(Lanes(0.0));
      s->pd = s->pdd = s->p;
      s->R.setConstant(Lanes(0.0));
      s->Rd = s->Rdd = s->R;
    }
    for (int l = 0; l < kLanes && j0 + l < 24; ++l) {
      LaneFrame<Lanes>& s = j0 + l < 12 ? a : b;
      const int k = (j0 + l) % 12;
      (k < 3 ? s.p(k) : s.R((k - 3) / 3, (k - 3) % 3)).d[l] = 1.0;
    }
    RowValues<Lanes> r;
    row_values(f, a, b, r);
    for (int i = 0; i < r.m; ++i)
      for (int c = 0; c < 24; ++c)
        for (int l = 0; l < kLanes && j0 + l < 24; ++l)
          if (r.D(i, c).d[l] != 0.0) out.push_back({i, c, j0 + l, r.D(i, c).d[l]});
  }
  return out;
}

// What every direction of the doubles pass shares: per end, the gradient of each row of
// A q̈ − b = D ẍ + ẋᵀHẋ over the end's 36 stacked entries of its J column (p, R, their rates and
// accelerations at q̈),
//   d(A q̈ − b)_i = (H_i ẍ)·dx + d(ẋᵀ H_i ẋ) + D_i·dẍ,
// and g = Dᵀλ (24: both ends' x). d(Dᵀλ) = (Σ_i λ_i H_i) dx is formed per direction.
struct ColumnMaps {
  Eigen::Matrix<double, kMaxRows, 36> G[2];
  Eigen::Matrix<double, 24, 1> g;
};

void column_maps(const NumericFrameSpec& f, const std::vector<HessianEntry>& hess,
                 const FrameState& a, const FrameState& b, CVecRef lambda, ColumnMaps& c) {
  RowValues<double> r;
  row_values(f, a, b, r);
  const Eigen::Matrix<double, 24, 1> xd = rates(a, b, false), xdd = rates(a, b, true);
  c.G[0].setZero();
  c.G[1].setZero();
  for (const HessianEntry& e : hess) {
    c.G[e.wrt / 12](e.row, e.wrt % 12) += e.h * xdd(e.col);
    c.G[e.wrt / 12](e.row, 12 + e.wrt % 12) += e.h * xd(e.col);
    c.G[e.col / 12](e.row, 12 + e.col % 12) += e.h * xd(e.wrt);
  }
  for (int i = 0; i < r.m; ++i) {
    for (int k = 0; k < 12; ++k) {
      c.G[0](i, 24 + k) = r.D(i, k);
      c.G[1](i, 24 + k) = r.D(i, 12 + k);
    }
  }
  c.g = r.D.topRows(r.m).transpose() * lambda;
}

// f(first, coordinate, length) for each run of consecutive coordinates in cols (sorted): cols[first
// .. first + length) = coordinate .. coordinate + length (one run for a tree's end).
template <class F>
void for_runs(const std::vector<Index>& cols, F&& f) {
  std::size_t i = 0;
  while (i < cols.size()) {
    std::size_t k = i + 1;
    while (k < cols.size() && cols[k] == cols[k - 1] + 1) ++k;
    f(static_cast<Index>(i), cols[i], static_cast<Index>(k - i));
    i = k;
  }
}

// lane_pass's results on doubles over every direction at once: the rows' tangents are linear in
// the ends' J columns (column_maps; the frame rows' counterpart of the frame acceleration
// derivatives of J. Carpentier and N. Mansard, "Analytical Derivatives of Rigid Body Dynamics
// Algorithms", RSS 2018), so nothing is lifted to lanes and each end's directions are
// matrix products with its J (q's columns, then q̇'s) by runs of consecutive coordinates:
//   d(A q̈ − b)                 += G_s J_s                 (every row, the end's 36 entries)
//   d(J_tᵀ D_tᵀ λ)  (t's rows)  += X_tᵀ Hλ[t, s] J_s(x)    (Hλ = Σ_i λ_i H_i; X_t = ∂x_t/∂q)
//   d(J_sᵀ D_sᵀ λ)  (s's rows)  += (d X_s)ᵀ g_s           (g = Dᵀλ; d X_s: J_s's rows 36 on)
// for each source end s and target end t. The pose x and X = ∂x/∂q do not depend on q̇: along q̇
// only the first product is not zero. P (12 (na + nb) doubles) holds X_tᵀ Hλ[t, s]. d_residual
// written (zeroed by the caller), d_force added to.
void block_pass(const NumericFrameSpec& f, const std::vector<HessianEntry>& hess, const End& a,
                const End& b, const LaneEnd& A, const LaneEnd& B, Index n, CVecRef lambda,
                double* P, MatRef d_residual, MatRef d_force) {
  const End* ends[2] = {&a, &b};
  const LaneEnd* lanes[2] = {&A, &B};
  ColumnMaps maps;
  column_maps(f, hess, *A.v, *B.v, lambda, maps);
  Eigen::Matrix<double, 24, 24> Hl = Eigen::Matrix<double, 24, 24>::Zero();
  for (const HessianEntry& e : hess) Hl(e.col, e.wrt) += lambda(e.row) * e.h;
  const Index m = d_residual.rows();
  using CMap = Eigen::Map<const Mat, 0, Eigen::OuterStride<>>;
  for (int s = 0; s < 2; ++s) {
    const std::vector<Index>& cs = ends[s]->cols;
    if (lanes[s]->J == nullptr || cs.empty()) continue;
    const auto ns = static_cast<Index>(cs.size());
    const Index ld = lanes[s]->ld;
    const CMap J(lanes[s]->J, ld, 2 * ns, Eigen::OuterStride<>(ld));
    for_runs(cs, [&](Index c, Index g, Index len) {
      d_residual.middleCols(g, len).noalias() +=
          maps.G[s].topRows(m).lazyProduct(J.block(0, c, 36, len));
      d_residual.middleCols(n + g, len).noalias() +=
          maps.G[s].block(0, 12, m, 24).lazyProduct(J.block(12, ns + c, 24, len));
    });
    double* Pt = P;
    for (int t = 0; t < 2; ++t) {
      const FrameState& X = *lanes[t]->v;
      const auto nt = static_cast<Index>(ends[t]->cols.size());
      Eigen::Map<Mat> Pm(Pt, nt, 12);
      Pm.noalias() = X.dp.transpose().lazyProduct(Hl.block(12 * t, 12 * s, 3, 12));
      Pm.noalias() += X.dR.transpose().lazyProduct(Hl.block(12 * t + 3, 12 * s, 9, 12));
      for_runs(ends[t]->cols, [&](Index ct, Index gt, Index lt) {
        for_runs(cs, [&](Index c, Index g, Index len) {
          d_force.block(gt, g, lt, len).noalias() +=
              Pm.middleRows(ct, lt).lazyProduct(J.block(0, c, 12, len));
        });
      });
      Pt += 12 * nt;
    }
    const Eigen::Map<const Eigen::Matrix<double, 12, 1>> gs(maps.g.data() + 12 * s);
    for (Index k = 0; k < ns; ++k) {
      const Index out = cs[static_cast<std::size_t>(k)];
      const Eigen::Map<const Eigen::Matrix<double, 12, Eigen::Dynamic>> dX(J.col(k).data() + 36, 12,
                                                                           ns);
      for_runs(cs, [&](Index c, Index g, Index len) {
        d_force.col(out).segment(g, len).noalias() +=
            dX.middleCols(c, len).transpose().lazyProduct(gs);
      });
    }
  }
}

// What the constraint and its wrench map share: the spec, the two ends and the slot layout.
class Core {
 public:
  Core(NumericFrameSpec f, End a, End b)
      : f_(std::move(f)), a_(std::move(a)), b_(std::move(b)), hess_(row_hessians(f_)) {
    names_ = row_names(f_);
    std::set<Index> all(a_.cols.begin(), a_.cols.end());
    all.insert(b_.cols.begin(), b_.cols.end());
    cols_.assign(all.begin(), all.end());
    disjoint_ = cols_.size() == a_.cols.size() + b_.cols.size();
    weld_twists_ =
        f_.kind == K::weld && twist_end(a_) && twist_end(b_) && a_.consecutive && b_.consecutive;
    const auto cols = static_cast<Index>(a_.cols.size() + b_.cols.size());
    slot_size_ = a_.scratch + b_.scratch + 24 * cols + tangent_room(a_) + tangent_room(b_);
  }
  [[nodiscard]] const NumericFrameSpec& spec() const { return f_; }
  [[nodiscard]] const std::vector<std::string>& names() const { return names_; }
  [[nodiscard]] const std::vector<Index>& columns() const { return cols_; }
  // The ends' scratch and columns (with()), then for tangent() the columns' tangents and the
  // tape tangents' room of an expressions end (as much as its scratch).
  [[nodiscard]] Index slot_size() const { return slot_size_; }
  // tangent_columns()'s ends' J (lane_room): dead once its columns are written, so they live in
  // the scratch every constraint of a ForwardData shares (ConstraintSlots::shared()), not in this
  // constraint's slot: N welds then reuse one area that stays cached instead of streaming N.
  [[nodiscard]] Index shared_size() const { return lane_room(a_) + lane_room(b_); }

  // The two ends' states and the rows at (q, q̇) with `slot` (slot_size() doubles); f gets
  // (a, b, rows).
  // The slot's room, or `own` sized to slot_size() when the slot is smaller (none given).
  double* room(Slot slot, std::vector<double>& own) const {
    if (static_cast<Index>(slot.size()) >= slot_size()) return slot.data();
    own.assign(static_cast<std::size_t>(slot_size()), 0.0);
    return own.data();
  }
  // The shared scratch's room (shared_size() doubles), or `own` sized to it when it is smaller.
  double* shared_room(const ConstraintSlots& slots, std::vector<double>& own) const {
    const Slot shared = slots.shared();
    if (static_cast<Index>(shared.size()) >= shared_size()) return shared.data();
    own.assign(static_cast<std::size_t>(shared_size()), 0.0);
    return own.data();
  }

  // Without a slot (a caller without a ForwardData: the residuals at an output sample) only what
  // with() uses is allocated, a tree end's scratch left to the tree's own forward workspace:
  // zeroing the whole slot_size() (the tree's derivative workspaces and the lanes' room) at every
  // call cost more than the rows themselves.
  template <class F>
  void with(CVecRef q, CVecRef qd, Slot slot, F&& f) const {
    const bool full = static_cast<Index>(slot.size()) >= slot_size();
    const auto own_scratch = [full](const End& e) {
      return full || e.spec.kind != NumericFrameEnd::Kind::tree ? e.scratch : Index{0};
    };
    const Index ka = own_scratch(a_), kb = own_scratch(b_);
    const auto na = static_cast<Index>(a_.cols.size()), nb = static_cast<Index>(b_.cols.size());
    std::vector<double> own;
    if (!full) own.assign(static_cast<std::size_t>(ka + kb + 12 * (na + nb)), 0.0);
    double* sa = full ? slot.data() : own.data();
    double* sb = sa + ka;
    double* da = sb + kb;
    double* db = da + 12 * na;
    FrameState A(da, da + 3 * na, na), B(db, db + 3 * nb, nb);
    end_state(a_, q, qd, sa, A, ka);
    end_state(b_, q, qd, sb, B, kb);
    RowValues<double> r;
    row_values(f_, A, B, r);
    f(A, B, r);
  }

  // The ends' states and the rows' values at (q, q̇) as forward() asks for them, then f(Sa, Sb, da,
  // db, r): a tree end through its twist columns (end_twists: the links reused from the
  // subsystem's slot when placed there at this state; the twists in da, db), in the same slot
  // layout as with() (a tree end's 7 twist doubles per column where with() keeps its 12 of dp, dR).
  template <class F>
  void with_twists(const ConstraintSlots& slots, CVecRef q, CVecRef qd, F&& f) const {
    with_end_twists(
        slots, q, qd,
        [&](const FrameState& Sa, const FrameState& Sb, const double* da, const double* db) {
          RowValues<double> r;
          row_values(f_, Sa, Sb, r);
          f(Sa, Sb, da, db, r);
        });
  }
  // with_twists() without the rows' values: f(Sa, Sb, da, db). `weld`: for weld_twist_rows
  // (end_twists).
  template <class F>
  void with_end_twists(const ConstraintSlots& slots, CVecRef q, CVecRef qd, F&& f,
                       bool weld = false) const {
    std::vector<double> own;
    double* base = room(slots.own(), own);
    const auto na = static_cast<Index>(a_.cols.size()), nb = static_cast<Index>(b_.cols.size());
    double* sa = base;
    double* sb = sa + a_.scratch;
    double* da = sb + b_.scratch;
    double* db = da + 12 * na;
    FrameState Sa(da, da + 3 * na, na), Sb(db, db + 3 * nb, nb);
    end_twists(a_, slots, q, qd, sa, Sa, da, weld);
    end_twists(b_, slots, q, qd, sb, Sb, db, weld);
    f(Sa, Sb, da, db);
  }

  // A and b at (q, q̇) (with_twists, add_twist_columns). `structural`: only A's columns of the
  // ends' coordinates (columns()) are zeroed and written, the rest of its rows left as they are
  // (ConstraintContext::structural_only: O(columns) per call, not O(n)).
  void evaluate(const ConstraintSlots& slots, CVecRef q, CVecRef qd, MatRef A, VecRef b,
                bool structural) const {
    if (weld_twists_) {
      with_end_twists(
          slots, q, qd,
          [&](const FrameState& Sa, const FrameState& Sb, const double* da, const double* db) {
            if (!structural) {
              zero_rows(A);
            } else if (!disjoint_) {
              for (const Index c : cols_) A.col(c).setZero();
            }
            weld_twist_rows(Sa, Sb, a_, da, b_, db, disjoint_, A, b);
          },
          true);
      return;
    }
    with_twists(slots, q, qd,
                [&](const FrameState& Sa, const FrameState& Sb, const double* da, const double* db,
                    const RowValues<double>& r) {
                  if (structural) {
                    for (const Index c : cols_) A.col(c).setZero();
                  } else {
                    zero_rows(A);
                  }
                  const int np = position_row_count(f_);
                  add_end_columns(a_, Sa, da, r, kPa, kRa, np, A);
                  add_end_columns(b_, Sb, db, r, kPb, kRb, np, A);
                  b = -(r.D.topRows(r.m) * rates(Sa, Sb, true) + r.Q.head(r.m));
                });
  }

  // Φ and Φ̇ = D ẋ from the same pass: p, R and their rates are with()'s (the same passes over the
  // links), without its 12 doubles of dp, dR per column.
  void residuals(const ConstraintSlots& slots, CVecRef q, CVecRef qd, VecRef phi,
                 VecRef phid) const {
    with_twists(slots, q, qd,
                [&](const FrameState& Sa, const FrameState& Sb, const double*, const double*,
                    const RowValues<double>& r) {
                  phi = r.phi.head(r.m);
                  phid = r.D.topRows(r.m) * rates(Sa, Sb, false);
                });
  }

  // d(A q̈ − b) and d(Aᵀλ) along (dq, dq̇) at fixed q̈, λ: the rows on dual numbers, with
  // A q̈ − b = D ẍ + ẋᵀHẋ (ẍ: the frames' acceleration at q̈) and Aᵀλ = Σ_end J_endᵀ D_endᵀ λ.
  void tangent(CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda, CVecRef dq, CVecRef dqd,
               Slot slot, VecRef d_residual, VecRef d_force) const {
    // The rows read the coordinates of their ends only (columns()): along a direction that moves
    // none of them both tangents are zero (linearize() runs one direction per coordinate).
    if (std::all_of(cols_.begin(), cols_.end(),
                    [&](Index c) { return dq(c) == 0.0 && dqd(c) == 0.0; })) {
      d_residual.setZero();
      return;
    }
    std::vector<double> own;
    double* base = room(slot, own);
    const auto na = static_cast<Index>(a_.cols.size()), nb = static_cast<Index>(b_.cols.size());
    double* sa = base;
    double* sb = sa + a_.scratch;
    double* va = sb + b_.scratch;  // the columns' values (as in with()), then their tangents
    double* vb = va + 12 * na;
    double* ta = vb + 12 * nb;
    double* tb = ta + 12 * na;
    double* xa = tb + 12 * nb;  // an expressions end's tape tangents follow its scratch
    double* xb = xa + tangent_room(a_);
    FrameState Va(va, va + 3 * na, na), Vb(vb, vb + 3 * nb, nb);
    FrameState Ta(ta, ta + 3 * na, na), Tb(tb, tb + 3 * nb, nb);
    DualFrame A, B;
    end_tangent(a_, q, qd, qdd, dq, dqd, {sa, xa}, Va, Ta, A);
    end_tangent(b_, q, qd, qdd, dq, dqd, {sb, xb}, Vb, Tb, B);
    RowValues<Dual> r;
    row_values(f_, A, B, r);
    for (int i = 0; i < r.m; ++i) d_residual(i) = tangent_of(residual_row(r, A, B, i));
    add_force_tangent(Va, Ta, a_.cols, r, kPa, kRa, lambda, d_force);
    add_force_tangent(Vb, Tb, b_.cols, r, kPb, kRb, lambda, d_force);
  }

  // tangent() along every direction of q and q̇ that moves an end, from the ends' J (lane_end):
  // d_residual (rows × 2n) written, d_force (n × 2n) added to. `structural`: only d_residual's
  // columns of those directions are written (O(columns), not O(n): the others are zero and left
  // as they are; ConstraintContext::structural_only). On doubles (block_pass), or `on_lanes`: the
  // rows lifted to kLanes directions per pass (lane_pass, the reference the tests compare
  // block_pass with).
  bool tangent_columns(const ConstraintSlots& slots, CVecRef q, CVecRef qd, CVecRef qdd,
                       CVecRef lambda, MatRef d_residual, MatRef d_force, bool structural,
                       bool on_lanes = false) const {
    std::vector<double> own, own_j;
    double* base = room(slots.own(), own);
    const auto na = static_cast<Index>(a_.cols.size()), nb = static_cast<Index>(b_.cols.size());
    double* sa = base;
    double* sb = sa + a_.scratch;
    double* va = sb + b_.scratch;  // the layout of tangent()
    double* vb = va + 12 * na;
    double* ta = vb + 12 * nb;
    double* tb = ta + 12 * na;
    double* xa = tb + 12 * nb;
    double* xb = xa + tangent_room(a_);
    double* ja = shared_room(slots, own_j);  // the ends' J (lane_room), every entry written
    double* jb = ja + lane_room(a_);
    FrameState Va(va, va + 3 * na, na), Vb(vb, vb + 3 * nb, nb);
    LaneEnd A = lane_end(a_, slots, q, qd, qdd, {sa, xa}, ja, Va);
    LaneEnd B = lane_end(b_, slots, q, qd, qdd, {sb, xb}, jb, Vb);
    const Index n = q.size(), nc = static_cast<Index>(cols_.size());
    if (structural) {
      for (const Index c : cols_) {
        d_residual.col(c).setZero();
        d_residual.col(n + c).setZero();
      }
    } else {
      d_residual.setZero();
    }
    if (!on_lanes) {  // the one-direction tangent's columns ta, tb hold block_pass's P
      block_pass(f_, hess_, a_, b_, A, B, n, lambda, ta, d_residual, d_force);
      return true;
    }
    // Direction i < nc along q of cols_[i], i ≥ nc along q̇ of cols_[i − nc]: the two kinds share
    // a pass (⌈2 nc / 8⌉ passes, not 2 ⌈nc / 8⌉).
    for (Index i0 = 0; i0 < 2 * nc; i0 += kLanes) {
      const int lanes = static_cast<int>(std::min<Index>(kLanes, 2 * nc - i0));
      Index out_col[kLanes];
      for (int l = 0; l < kLanes; ++l) {
        const Index i = i0 + l;
        const bool rate = i >= nc;
        const Index g = l < lanes ? cols_[static_cast<std::size_t>(i % nc)] : -1;
        out_col[l] = (rate ? n : 0) + g;
        A.col[l] = lane_column(a_, g, rate);
        B.col[l] = lane_column(b_, g, rate);
      }
      lane_pass(f_, a_, b_, A, B, lambda, out_col, lanes, d_residual, d_force);
    }
    return true;
  }

  [[nodiscard]] const End& a() const { return a_; }
  [[nodiscard]] const End& b() const { return b_; }

 private:
  NumericFrameSpec f_;
  End a_, b_;
  std::vector<HessianEntry> hess_;
  std::vector<std::string> names_;
  std::vector<Index> cols_;
  bool disjoint_ = false;     // the ends share no column
  bool weld_twists_ = false;  // evaluate() by weld_twist_rows
  Index slot_size_ = 0;
};

// ẋ and ẍ|q̈=0 of both ends as the 24-vectors of RowValues::D's columns.
Eigen::Matrix<double, 24, 1> rates(const FrameState& a, const FrameState& b, bool second) {
  Eigen::Matrix<double, 24, 1> x;
  const Eigen::Vector3d& pa = second ? a.pdd : a.pd;
  const Eigen::Vector3d& pb = second ? b.pdd : b.pd;
  const Eigen::Matrix3d& Ra = second ? a.Rdd : a.Rd;
  const Eigen::Matrix3d& Rb = second ? b.Rdd : b.Rd;
  for (int k = 0; k < 3; ++k) {
    x(kPa + k) = pa(k);
    x(kPb + k) = pb(k);
  }
  for (int k = 0; k < 9; ++k) {
    x(kRa + k) = Ra(k / 3, k % 3);
    x(kRb + k) = Rb(k / 3, k % 3);
  }
  return x;
}

class NumericFrameRows final : public Constraint, public ConstraintColumns {
 public:
  explicit NumericFrameRows(std::shared_ptr<const Core> core) : core_(std::move(core)) {}
  [[nodiscard]] Index rows() const override { return static_cast<Index>(core_->names().size()); }
  [[nodiscard]] const std::vector<std::string>& row_names() const override {
    return core_->names();
  }
  [[nodiscard]] Index slot_size() const override { return core_->slot_size(); }
  [[nodiscard]] Index shared_slot_size() const override { return core_->shared_size(); }
  [[nodiscard]] std::vector<std::vector<Index>> row_columns() const override {
    return std::vector<std::vector<Index>>(static_cast<std::size_t>(rows()), core_->columns());
  }
  void evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override {
    core_->evaluate(ctx.slots, q, qd, A, b, ctx.structural_only);
  }
  void position_residual(const ConstraintContext& ctx, CVecRef q, VecRef phi) const override {
    // The rates are not used: q stands in for q̇.
    core_->with(q, q, ctx.slots.own(),
                [&](const FrameState&, const FrameState&, const RowValues<double>& r) {
                  phi = r.phi.head(r.m);
                });
  }
  void velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                         VecRef phid) const override {
    core_->with(q, qd, ctx.slots.own(),
                [&](const FrameState& sa, const FrameState& sb, const RowValues<double>& r) {
                  phid = r.D.topRows(r.m) * rates(sa, sb, false);
                });
  }
  // Both from one pass over the ends (Φ does not depend on the rates).
  void residuals(const ConstraintContext& ctx, CVecRef q, CVecRef qd, VecRef phi,
                 VecRef phid) const override {
    core_->residuals(ctx.slots, q, qd, phi, phid);
  }
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef d_residual, VecRef d_force) const override {
    core_->tangent(q, qd, qdd, lambda, dq, dqd, ctx.slots.own(), d_residual, d_force);
    return true;
  }
  // No end moves with t (an expressions end of t is refused when the rows are built): 0, exact.
  bool time_tangent(const ConstraintContext&, CVecRef, CVecRef, CVecRef, CVecRef, VecRef d_residual,
                    VecRef) const override {
    d_residual.setZero();
    return true;
  }
  bool tangent_columns(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                       CVecRef lambda, MatRef d_residual, MatRef d_force) const override {
    return core_->tangent_columns(ctx.slots, q, qd, qdd, lambda, d_residual, d_force,
                                  ctx.structural_only);
  }

 private:
  std::shared_ptr<const Core> core_;
};

class NumericFrameWrenches final : public FrameWrenches {
 public:
  NumericFrameWrenches(std::shared_ptr<const Core> core, Index n)
      : FrameWrenches(core->spec().name, core->spec().frame_a, core->spec().frame_b,
                      core->spec().kind, static_cast<Index>(core->names().size())),
        core_(std::move(core)),
        n_(n) {}
  using FrameWrenches::evaluate;
  [[nodiscard]] Workspace workspace() const override {
    return Workspace{std::vector<double>(static_cast<std::size_t>(core_->slot_size())),
                     {},
                     Mat(rows(), 6),
                     Mat(rows(), 6)};
  }
  void evaluate(CVecRef q, const Vec& lambda, Workspace& ws, FrameWrench& w) const override {
    core_->with(q, q, Slot(ws.out),
                [&](const FrameState& a, const FrameState& b, const RowValues<double>& r) {
                  twist_map(r, a.R, kPa, kRa, ws.Ga);
                  twist_map(r, b.R, kPb, kRb, ws.Gb);
                  w.position_a = a.p;
                  w.rotation_a = a.R;
                  w.position_b = b.p;
                  w.rotation_b = b.R;
                });
    wrench_from_maps(ws.Ga, ws.Gb, lambda, w);
  }
  void maps(const Vec& q, Mat& Ga, Mat& Gb) const override {
    Ga.resize(rows(), 6);
    Gb.resize(rows(), 6);
    core_->with(q, q, {},
                [&](const FrameState& a, const FrameState& b, const RowValues<double>& r) {
                  twist_map(r, a.R, kPa, kRa, Ga);
                  twist_map(r, b.R, kPb, kRb, Gb);
                });
  }
  void jacobians(const Vec& q, Mat& Ja, Mat& Jb) const override {
    core_->with(q, q, {}, [&](const FrameState& a, const FrameState& b, const RowValues<double>&) {
      twist_jacobian(a, core_->a().cols, n_, Ja);
      twist_jacobian(b, core_->b().cols, n_, Jb);
    });
  }
  [[nodiscard]] const Core& core() const { return *core_; }
  void jacobians(CVecRef q, Workspace& ws, Mat& Ja, Mat& Jb) const override {
    core_->with(q, q, Slot(ws.out),
                [&](const FrameState& a, const FrameState& b, const RowValues<double>&) {
                  twist_jacobian(a, core_->a().cols, n_, Ja);
                  twist_jacobian(b, core_->b().cols, n_, Jb);
                });
  }

 private:
  std::shared_ptr<const Core> core_;
  Index n_;
};

}  // namespace

bool numeric_frame_columns_on_lanes(const FrameConstraint& c, const ConstraintContext& ctx,
                                    CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
                                    MatRef d_residual, MatRef d_force) {
  const auto* w = dynamic_cast<const NumericFrameWrenches*>(&c.wrench());
  return w != nullptr && w->core().tangent_columns(ctx.slots, q, qd, qdd, lambda, d_residual,
                                                   d_force, ctx.structural_only, true);
}

std::pair<Eigen::Vector3d, Eigen::Vector3d> perpendicular_pair(const Eigen::Vector3d& u) {
  int k = 0;
  double best = 2.0;
  for (int i = 0; i < 3; ++i) {
    const double c = std::abs(u(i));
    if (c < best - 1e-12) {
      best = c;
      k = i;
    }
  }
  Eigen::Vector3d e = Eigen::Vector3d::Zero();
  e(k) = 1.0;
  const Eigen::Vector3d n1 = u.cross(e).normalized();
  return {n1, u.cross(n1)};
}

std::shared_ptr<FrameConstraint> make_numeric_frame_constraint(
    const NumericFrameSpec& f, NumericFrameEnd a, NumericFrameEnd b,
    const std::vector<std::string>& system_coordinates, std::shared_ptr<SymbolTable> symbols) {
  const bool needs_rotation = f.kind == K::weld || f.kind == K::hinge || f.kind == K::level;
  for (const auto* e : {&a, &b}) {
    if (needs_rotation && e->kind == NumericFrameEnd::Kind::expressions && !e->pose.has_rotation &&
        (e == &a || f.kind != K::level)) {
      throw DefinitionError(std::string("a ") + to_string(f.kind) +
                            " needs the orientation of frame '" +
                            (e == &a ? f.frame_a : f.frame_b) +
                            "', but it has none (a body without `rotation`: use ball or distance, "
                            "or give the body a rotation)");
    }
  }
  End ea = make_end(std::move(a), system_coordinates, *symbols, f.frame_a);
  End eb = make_end(std::move(b), system_coordinates, *symbols, f.frame_b);
  auto core = std::make_shared<const Core>(f, std::move(ea), std::move(eb));
  return std::make_shared<FrameConstraint>(
      std::make_shared<NumericFrameRows>(core),
      std::make_shared<NumericFrameWrenches>(core, static_cast<Index>(system_coordinates.size())));
}

}  // namespace ukdyn::symbolic
