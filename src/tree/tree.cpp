// The recursive rigid-body algorithms over a tree (ukdyn/tree/tree.hpp): placement of the links,
// the composite-rigid-body algorithm (CRBA, Featherstone 2008 §6.2, Table 6.2) and the recursive
// Newton–Euler algorithm (RNEA, §5.3, Table 5.1), in world coordinates about the world origin
// (§2.9). The algorithms are templates on the scalar so that the same code runs on doubles (the
// hot path, workspace in the caller's slot) and on Eigen's AutoDiffScalar (∂M/∂θ for the
// Christoffel matrix).
#include "ukdyn/tree/tree.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <new>
#include <set>
#include <unsupported/Eigen/AutoDiff>

namespace ukdyn::tree {

namespace {

template <class S>
using V3 = Eigen::Matrix<S, 3, 1>;
template <class S>
using M3 = Eigen::Matrix<S, 3, 3>;

// What one evaluation computes per link (the workspace).
template <class S>
struct LinkState {
  M3<S> R;       // link frame → world
  V3<S> p;       // link frame origin in the world
  V3<S> sw, sv;  // motion axis S = (sw, sv) about the world origin (movable joints)
  // Spatial inertia about the world origin as (mass m, first moment h = m c, rotational inertia
  // Ī = I_c + m(|c|² 1 − c cᵀ)): the link's own and the composite of its subtree (CRBA).
  S m_own, m;
  V3<S> h_own, h;
  M3<S> I_own, I;
  V3<S> vw, vv, aw, av;  // velocity and velocity-product acceleration (RNEA)
  V3<S> fn, ff;          // force of the subtree (RNEA)
};

static_assert(sizeof(LinkState<double>) % sizeof(double) == 0 &&
                  alignof(LinkState<double>) <= alignof(double),
              "LinkState<double> must live in a slot of doubles");
constexpr Index kLinkDoubles = static_cast<Index>(sizeof(LinkState<double>) / sizeof(double));

// a · b summed in the order a0 b0 + a1 b1 + a2 b2 whatever the operands' addresses: Eigen's
// vectorised reductions peel the first element when the data is not aligned, which changes the
// order of the sums with the address (the slot's), and the last bits with it.
template <class S>
S dot3(const V3<S>& a, const V3<S>& b) {
  return a(0) * b(0) + a(1) * b(1) + a(2) * b(2);
}

// Rotation by angle th about the unit axis a (Rodrigues): cos th 1 + (1 − cos th) a aᵀ + sin th [a]×.
template <class S>
M3<S> axis_rotation(const Eigen::Vector3d& a, const S& th) {
  using std::cos;
  using std::sin;
  const S c = cos(th), s = sin(th), t = S(1.0) - c;
  M3<S> R;
  R(0, 0) = c + t * a.x() * a.x();
  R(0, 1) = t * a.x() * a.y() - s * a.z();
  R(0, 2) = t * a.x() * a.z() + s * a.y();
  R(1, 0) = t * a.y() * a.x() + s * a.z();
  R(1, 1) = c + t * a.y() * a.y();
  R(1, 2) = t * a.y() * a.z() - s * a.x();
  R(2, 0) = t * a.z() * a.x() - s * a.y();
  R(2, 1) = t * a.z() * a.y() + s * a.x();
  R(2, 2) = c + t * a.z() * a.z();
  return R;
}

// Link poses, motion axes and own inertias at the joint variables theta (Featherstone §4.1: the
// forward pass of placement, parent before child).
template <class S>
void place(const Model& m, const std::vector<int>& ti, const S* theta, LinkState<S>* ws) {
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const Link& L = m.links[i];
    LinkState<S>& w = ws[i];
    M3<S> Rp;
    V3<S> pp;
    if (L.parent < 0) {
      Rp = m.root_rotation.cast<S>();
      pp = m.root_translation.cast<S>();
    } else {
      Rp = ws[L.parent].R;
      pp = ws[L.parent].p;
    }
    const M3<S> Rj = Rp * L.origin_rotation.cast<S>();
    const V3<S> pj = pp + Rp * L.origin_translation.cast<S>();
    if (L.type == JointType::revolute) {
      w.R = Rj * axis_rotation<S>(L.axis, theta[ti[i]]);
      w.p = pj;
      w.sw = Rj * L.axis.cast<S>();
      w.sv = pj.cross(w.sw);  // v_O = ω × (0 − p_j) = p_j × z
    } else if (L.type == JointType::prismatic) {
      w.R = Rj;
      w.sw.setZero();
      w.sv = Rj * L.axis.cast<S>();
      w.p = pj + w.sv * theta[ti[i]];
    } else {
      w.R = Rj;
      w.p = pj;
    }
    if (L.mass == 0.0 && L.inertia.isZero(0.0)) {  // a massless frame (flange, tool0)
      w.m_own = S(0.0);
      w.h_own.setZero();
      w.I_own.setZero();
      continue;
    }
    const V3<S> c = w.p + w.R * L.com.cast<S>();
    w.m_own = S(L.mass);
    w.h_own = c * w.m_own;
    w.I_own = w.R * L.inertia.cast<S>() * w.R.transpose() +
              w.m_own * (dot3(c, c) * M3<S>::Identity() - c * c.transpose());
  }
}

// (n, f) = I (w, v) for the spatial inertia (m, h, Ī) about the world origin:
// n = Ī ω + h × v, f = m v − h × ω.
template <class S>
void apply_inertia(const S& m, const V3<S>& h, const M3<S>& I, const V3<S>& w, const V3<S>& v,
                   V3<S>& n, V3<S>& f) {
  n = I * w + h.cross(v);
  f = m * v - h.cross(w);
}

// Composite inertias of the subtrees (CRBA's backward sum, Featherstone Table 6.2).
template <class S>
void composite(const Model& m, LinkState<S>* ws) {
  const std::size_t n = m.links.size();
  for (std::size_t i = 0; i < n; ++i) {
    ws[i].m = ws[i].m_own;
    ws[i].h = ws[i].h_own;
    ws[i].I = ws[i].I_own;
  }
  for (std::size_t i = n; i-- > 0;) {
    const int p = m.links[i].parent;
    if (p < 0) continue;
    ws[p].m += ws[i].m;
    ws[p].h += ws[i].h;
    ws[p].I += ws[i].I;
  }
}

// M_θ (nt × nt, column-major in Mt) from the composite inertias: M_ii = S_iᵀ I^c_i S_i and, for
// each ancestor j of i, M_ij = M_ji = S_jᵀ (I^c_i S_i) (Featherstone Table 6.2).
template <class S>
void crba(const Model& m, const std::vector<int>& ti, const LinkState<S>* ws, S* Mt, Index nt) {
  for (Index k = 0; k < nt * nt; ++k) Mt[k] = S(0.0);
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const int a = ti[i];
    if (a < 0) continue;
    V3<S> n, f;
    apply_inertia(ws[i].m, ws[i].h, ws[i].I, ws[i].sw, ws[i].sv, n, f);
    Mt[a + a * nt] = dot3(ws[i].sw, n) + dot3(ws[i].sv, f);
    for (int j = m.links[i].parent; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
      const int b = ti[static_cast<std::size_t>(j)];
      if (b < 0) continue;
      const S v = dot3(ws[j].sw, n) + dot3(ws[j].sv, f);
      Mt[a + b * nt] = v;
      Mt[b + a * nt] = v;
    }
  }
}

// C(θ, θ̇) θ̇ by the RNEA with no gravity and θ̈ = 0 (Featherstone Table 5.1 in world coordinates):
// v_i = v_p + S_i θ̇_i, a_i = a_p + (v_p × S_i) θ̇_i (Ṡ_i = v_i × S_i = v_p × S_i),
// f_i = I_i a_i + v_i ×* I_i v_i, then τ_i = S_iᵀ f_i with f summed into the parent.
template <class S>
void velocity_products(const Model& m, const std::vector<int>& ti, const S* thetad,
                       LinkState<S>* ws, S* tau) {
  const std::size_t n = m.links.size();
  for (std::size_t i = 0; i < n; ++i) {
    LinkState<S>& w = ws[i];
    const int p = m.links[i].parent;
    if (p < 0) {
      w.vw.setZero();
      w.vv.setZero();
      w.aw.setZero();
      w.av.setZero();
    } else {
      w.vw = ws[p].vw;
      w.vv = ws[p].vv;
      w.aw = ws[p].aw;
      w.av = ws[p].av;
    }
    if (ti[i] >= 0) {
      const S qd = thetad[ti[i]];
      // (v_p × S) = (ω_p × s_w, ω_p × s_v + v_p × s_w)
      w.aw += w.vw.cross(w.sw) * qd;
      w.av += (w.vw.cross(w.sv) + w.vv.cross(w.sw)) * qd;
      w.vw += w.sw * qd;
      w.vv += w.sv * qd;
    }
    const Link& L = m.links[i];
    if (L.mass == 0.0 && L.inertia.isZero(0.0)) {  // a massless frame: no force of its own
      w.fn.setZero();
      w.ff.setZero();
      continue;
    }
    V3<S> n1, f1, n2, f2;
    apply_inertia(w.m_own, w.h_own, w.I_own, w.vw, w.vv, n1, f1);  // momentum I v
    apply_inertia(w.m_own, w.h_own, w.I_own, w.aw, w.av, n2, f2);  // I a
    // (ω, v) ×* (n, f) = (ω × n + v × f, ω × f)
    w.fn = n2 + w.vw.cross(n1) + w.vv.cross(f1);
    w.ff = f2 + w.vw.cross(f1);
  }
  for (std::size_t i = n; i-- > 0;) {
    LinkState<S>& w = ws[i];
    if (ti[i] >= 0) tau[ti[i]] = dot3(w.sw, w.fn) + dot3(w.sv, w.ff);
    const int p = m.links[i].parent;
    if (p >= 0) {
      ws[p].fn += w.fn;
      ws[p].ff += w.ff;
    }
  }
}

// G_θ from the composite inertias: the force I^c_i (0, −g) of each subtree held against gravity,
// G_i = S_iᵀ (−h^c_i × g, −m^c_i g).
template <class S>
void gravity_forces(const Model& m, const std::vector<int>& ti, const LinkState<S>* ws, S* G) {
  const V3<S> g = m.gravity.cast<S>();
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (ti[i] < 0) continue;
    G[ti[i]] = -dot3(ws[i].sw, V3<S>(ws[i].h.cross(g))) - dot3(ws[i].sv, g) * ws[i].m;
  }
}

// The inverse dynamics τ = M(θ) θ̈ + C(θ, θ̇) θ̇ + G(θ) by the RNEA with θ̈ (Featherstone Table 5.1
// in world coordinates), gravity as the fictitious base acceleration a_0 = (0, −g) (§5.3):
// v_i = v_p + S_i θ̇_i, a_i = a_p + S_i θ̈_i + (v_p × S_i) θ̇_i, f_i = I_i a_i + v_i ×* I_i v_i,
// τ_i = S_iᵀ f_i with f summed into the parent. Run on dual numbers it gives the exact
// directional derivatives of τ (the derivatives of the dynamics, docs/derivatives.md).
template <class S>
void inverse_dynamics(const Model& m, const std::vector<int>& ti, const S* thetad, const S* thetadd,
                      LinkState<S>* ws, S* tau) {
  const std::size_t n = m.links.size();
  for (std::size_t i = 0; i < n; ++i) {
    LinkState<S>& w = ws[i];
    const int p = m.links[i].parent;
    if (p < 0) {
      w.vw.setZero();
      w.vv.setZero();
      w.aw.setZero();
      w.av = -m.gravity.cast<S>();
    } else {
      w.vw = ws[p].vw;
      w.vv = ws[p].vv;
      w.aw = ws[p].aw;
      w.av = ws[p].av;
    }
    if (ti[i] >= 0) {
      const S qd = thetad[ti[i]], qdd = thetadd[ti[i]];
      w.aw += w.vw.cross(w.sw) * qd + w.sw * qdd;
      w.av += (w.vw.cross(w.sv) + w.vv.cross(w.sw)) * qd + w.sv * qdd;
      w.vw += w.sw * qd;
      w.vv += w.sv * qd;
    }
    V3<S> n1, f1, n2, f2;
    apply_inertia(w.m_own, w.h_own, w.I_own, w.vw, w.vv, n1, f1);
    apply_inertia(w.m_own, w.h_own, w.I_own, w.aw, w.av, n2, f2);
    w.fn = n2 + w.vw.cross(n1) + w.vv.cross(f1);
    w.ff = f2 + w.vw.cross(f1);
  }
  for (std::size_t i = n; i-- > 0;) {
    LinkState<S>& w = ws[i];
    if (ti[i] >= 0) tau[ti[i]] = dot3(w.sw, w.fn) + dot3(w.sv, w.ff);
    const int p = m.links[i].parent;
    if (p >= 0) {
      ws[p].fn += w.fn;
      ws[p].ff += w.ff;
    }
  }
}

bool finite3(const Eigen::Vector3d& v) { return v.allFinite(); }

}  // namespace

// ------------------------------------------------------------------------------ validation

void validate(const Model& model) {
  const auto n = static_cast<int>(model.links.size());
  const auto nq = static_cast<Index>(model.coordinates.size());
  if (!model.root_rotation.allFinite() || !model.root_translation.allFinite() ||
      !model.gravity.allFinite())
    throw Error("tree '" + model.name + "': the mount or the gravity is not finite");
  std::set<std::string> names{model.root_name};
  for (int i = 0; i < n; ++i) {
    const Link& L = model.links[static_cast<std::size_t>(i)];
    const std::string where = "tree '" + model.name + "', link '" + L.name + "'";
    if (!names.insert(L.name).second) throw Error(where + ": the link name is used twice");
    if (L.parent < -1 || L.parent >= i)
      throw Error(where + ": its parent must be the root or a link listed before it");
    if (!L.origin_rotation.allFinite() || !finite3(L.origin_translation) || !finite3(L.axis) ||
        !std::isfinite(L.offset) || !std::isfinite(L.mass) || !finite3(L.com) ||
        !L.inertia.allFinite())
      throw Error(where + ": a number is not finite");
    const Eigen::Matrix3d RtR = L.origin_rotation.transpose() * L.origin_rotation;
    if ((RtR - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-9 ||
        L.origin_rotation.determinant() < 0.0)
      throw Error(where + ": the origin rotation is not a rotation");
    if (L.type == JointType::fixed) {
      if (!L.terms.empty()) throw Error(where + ": a fixed joint has no variable");
    } else {
      if (std::abs(L.axis.norm() - 1.0) > 1e-9)
        throw Error(where + ": the axis is not a unit vector");
      if (L.terms.empty()) throw Error(where + ": a movable joint needs a coordinate");
      for (const Term& t : L.terms) {
        if (t.coordinate < 0 || t.coordinate >= nq || !std::isfinite(t.coefficient))
          throw Error(where + ": its variable names no coordinate of the tree");
      }
    }
    if (L.mass < 0.0) throw Error(where + ": negative mass " + std::to_string(L.mass));
    const double scale = std::max(1.0, L.inertia.cwiseAbs().maxCoeff());
    if ((L.inertia - L.inertia.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale)
      throw Error(where + ": the inertia is not symmetric");
    const Eigen::Vector3d ev =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(L.inertia, Eigen::EigenvaluesOnly)
            .eigenvalues();
    if (ev.minCoeff() < -1e-12 * scale)
      throw Error(where + ": the inertia is not positive semi-definite (smallest eigenvalue " +
                  std::to_string(ev.minCoeff()) + ")");
  }
  for (const Point& p : model.points) {
    if (p.link < -1 || p.link >= n || !finite3(p.xyz))
      throw Error("tree '" + model.name + "', point '" + p.name + "': no such link, or not finite");
  }
}

// ------------------------------------------------------------------------------ TreeSubsystem

namespace {

// The workspace in a slot of doubles: the link states, then θ, θ̇, M_θ (nt × nt) and τ_θ.
struct Workspace {
  LinkState<double>* links;
  double* theta;
  double* thetad;
  double* Mt;
  double* tau;
};

Index workspace_doubles(std::size_t links, Index nt) {
  return static_cast<Index>(links) * kLinkDoubles + 3 * nt + nt * nt;
}

Workspace map_workspace(double* data, std::size_t links, Index nt) {
  Workspace w{};
  w.links = reinterpret_cast<LinkState<double>*>(data);
  for (std::size_t i = 0; i < links; ++i) new (&w.links[i]) LinkState<double>;
  double* rest = data + static_cast<Index>(links) * kLinkDoubles;
  w.theta = rest;
  w.thetad = rest + nt;
  w.tau = rest + 2 * nt;
  w.Mt = rest + 3 * nt;
  return w;
}

}  // namespace

// ------------------------------------------------------------------------------ derivatives

namespace {

// One tangent direction: value and directional derivative (Eigen's forward-mode scalar with a
// fixed one-entry derivative: no heap, trivially copyable into a slot of doubles).
using Dual = Eigen::AutoDiffScalar<Eigen::Matrix<double, 1, 1>>;
// Eigen aligns fixed-size vectors of 16 bytes' multiples (LinkState<Dual>) to 16: the workspace
// starts at the first 16-aligned double of its part of the slot (one double of room).
static_assert(sizeof(LinkState<Dual>) % sizeof(double) == 0 && alignof(LinkState<Dual>) <= 16,
              "LinkState<Dual> must live in a slot of doubles");
constexpr Index kDualLinkDoubles = static_cast<Index>(sizeof(LinkState<Dual>) / sizeof(double));
constexpr Index kDualDoubles = static_cast<Index>(sizeof(Dual) / sizeof(double));

Dual dual(double value, double tangent) {
  return Dual(value, Eigen::Matrix<double, 1, 1>::Constant(tangent));
}

Index tangent_workspace_doubles(std::size_t links, Index nt) {
  return static_cast<Index>(links) * kDualLinkDoubles + 4 * nt * kDualDoubles + 1;
}

}  // namespace

namespace {

// Lumps a rigid body (mass m, CoM c, inertia I about c, both in K's frame) into link K.
void lump(Link& K, double m, const Eigen::Vector3d& c, const Eigen::Matrix3d& I) {
  const double M = K.mass + m;
  if (!(M > 0.0)) {  // two massless frames, or a mass-less inertia: nothing to shift
    K.inertia += I;
    return;
  }
  const Eigen::Vector3d com = (K.mass * K.com + m * c) / M;
  auto shift = [&com](double mass, const Eigen::Vector3d& at) {
    const Eigen::Vector3d d = at - com;
    return Eigen::Matrix3d(mass * (d.dot(d) * Eigen::Matrix3d::Identity() - d * d.transpose()));
  };
  K.inertia = K.inertia + shift(K.mass, K.com) + I + shift(m, c);
  K.mass = M;
  K.com = com;
}

// The tree with every link on a fixed joint merged into its nearest movable ancestor (its inertia
// lumped there, its children re-parented with the composed origin), where each link of `m` is in
// it, and V0: the potential of the masses whose joints up to the root are all fixed.
Model merge_fixed_links(const Model& m, std::vector<TreeSubsystem::Placement>& where, double& V0) {
  Model out = m;
  out.links.clear();
  out.points.clear();
  where.assign(m.links.size(), {});
  V0 = 0.0;
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const Link& L = m.links[i];
    TreeSubsystem::Placement parent;  // the root frame
    if (L.parent >= 0) parent = where[static_cast<std::size_t>(L.parent)];
    const Eigen::Matrix3d Rj = parent.R * L.origin_rotation;
    const Eigen::Vector3d pj = parent.p + parent.R * L.origin_translation;
    if (L.type != JointType::fixed) {
      Link K = L;
      K.parent = parent.link;
      K.origin_rotation = Rj;
      K.origin_translation = pj;
      out.links.push_back(std::move(K));
      where[i].link = static_cast<int>(out.links.size()) - 1;
      continue;
    }
    where[i] = {parent.link, Rj, pj};
    if (L.mass == 0.0 && L.inertia.isZero(0.0)) continue;
    const Eigen::Vector3d c = pj + Rj * L.com;
    if (parent.link < 0) {  // fixed in the world: a constant potential −m g · c
      V0 -= L.mass * m.gravity.dot(m.root_rotation * c + m.root_translation);
    } else {
      lump(out.links[static_cast<std::size_t>(parent.link)], L.mass, c,
           Rj * L.inertia * Rj.transpose());
    }
  }
  return out;
}

}  // namespace

TreeSubsystem::TreeSubsystem(Model model, bool merge_fixed) : model_(std::move(model)) {
  validate(model_);
  if (merge_fixed) {
    merged_ = merge_fixed_links(model_, placement_, potential0_);
  } else {
    merged_ = model_;
    placement_.resize(model_.links.size());
    for (std::size_t i = 0; i < placement_.size(); ++i) placement_[i].link = static_cast<int>(i);
  }
  theta_index_.assign(merged_.links.size(), -1);
  for (std::size_t i = 0; i < merged_.links.size(); ++i) {
    if (merged_.links[i].type != JointType::fixed) theta_index_[i] = static_cast<int>(n_theta_++);
  }
  // The forward workspace, then the derivatives' (dual numbers, inverse_dynamics_tangent()).
  slot_size_ = workspace_doubles(merged_.links.size(), n_theta_) +
               tangent_workspace_doubles(merged_.links.size(), n_theta_);
}

int TreeSubsystem::link_index(const std::string& name) const {
  if (name == model_.root_name) return -1;
  for (std::size_t i = 0; i < model_.links.size(); ++i) {
    if (model_.links[i].name == name) return static_cast<int>(i);
  }
  return -2;
}

namespace {

// Evaluates with the caller's slot or, without one, a buffer of its own.
template <class F>
void with_workspace(Slot slot, Index size, std::size_t links, Index nt, F&& f) {
  if (static_cast<Index>(slot.size()) >= size) {
    f(map_workspace(slot.data(), links, nt));
  } else {
    std::vector<double> buffer(static_cast<std::size_t>(size));
    f(map_workspace(buffer.data(), links, nt));
  }
}

// θ = offset + T q and θ̇ = T q̇ (qd may be null).
void theta_of(const Model& m, const std::vector<int>& ti, const double* q, const double* qd,
              double* theta, double* thetad) {
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (ti[i] < 0) continue;
    const Link& L = m.links[i];
    double th = L.offset, thd = 0.0;
    for (const Term& t : L.terms) {
      th += t.coefficient * q[t.coordinate];
      if (qd) thd += t.coefficient * qd[t.coordinate];
    }
    theta[ti[i]] = th;
    if (qd) thetad[ti[i]] = thd;
  }
}

// M_q = Tᵀ M_θ T.
void to_coordinates(const Model& m, const std::vector<int>& ti, const double* Mt, Index nt,
                    MatRef M) {
  M.setZero();
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (ti[i] < 0) continue;
    for (std::size_t j = 0; j < m.links.size(); ++j) {
      if (ti[j] < 0) continue;
      const double v = Mt[ti[i] + ti[j] * nt];
      if (v == 0.0) continue;
      for (const Term& a : m.links[i].terms) {
        for (const Term& b : m.links[j].terms)
          M(a.coordinate, b.coordinate) += a.coefficient * b.coefficient * v;
      }
    }
  }
}

// x_q = Tᵀ x_θ.
void to_coordinates(const Model& m, const std::vector<int>& ti, const double* x, VecRef out) {
  out.setZero();
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (ti[i] < 0) continue;
    for (const Term& a : m.links[i].terms) out(a.coordinate) += a.coefficient * x[ti[i]];
  }
}

}  // namespace

void TreeSubsystem::mass(const EvalContext& c, CVecRef q, MatRef M) const {
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_of(merged_, theta_index_, q.data(), nullptr, w.theta, nullptr);
    place(merged_, theta_index_, w.theta, w.links);
    composite(merged_, w.links);
    crba(merged_, theta_index_, w.links, w.Mt, n_theta_);
    to_coordinates(merged_, theta_index_, w.Mt, n_theta_, M);
  });
}

void TreeSubsystem::coriolis_times_qd(const EvalContext& c, CVecRef q, CVecRef qd,
                                      VecRef Cqd) const {
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_of(merged_, theta_index_, q.data(), qd.data(), w.theta, w.thetad);
    place(merged_, theta_index_, w.theta, w.links);
    velocity_products(merged_, theta_index_, w.thetad, w.links, w.tau);
    to_coordinates(merged_, theta_index_, w.tau, Cqd);
  });
}

void TreeSubsystem::gravity(const EvalContext& c, CVecRef q, VecRef G) const {
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_of(merged_, theta_index_, q.data(), nullptr, w.theta, nullptr);
    place(merged_, theta_index_, w.theta, w.links);
    composite(merged_, w.links);
    gravity_forces(merged_, theta_index_, w.links, w.tau);
    to_coordinates(merged_, theta_index_, w.tau, G);
  });
}

double TreeSubsystem::potential(const EvalContext& c, CVecRef q) const {
  double V = 0.0;
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_of(merged_, theta_index_, q.data(), nullptr, w.theta, nullptr);
    place(merged_, theta_index_, w.theta, w.links);
    Eigen::Vector3d h = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < merged_.links.size(); ++i) h += w.links[i].h_own;
    V = -dot3<double>(merged_.gravity, h) + potential0_;  // V = −Σ m g·c
  });
  return V;
}

double TreeSubsystem::dynamics(const EvalContext& c, CVecRef q, CVecRef qd, MatRef M, VecRef Cqd,
                               VecRef G) const {
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_of(merged_, theta_index_, q.data(), qd.data(), w.theta, w.thetad);
    place(merged_, theta_index_, w.theta, w.links);
    composite(merged_, w.links);
    crba(merged_, theta_index_, w.links, w.Mt, n_theta_);
    to_coordinates(merged_, theta_index_, w.Mt, n_theta_, M);
    gravity_forces(merged_, theta_index_, w.links, w.tau);
    to_coordinates(merged_, theta_index_, w.tau, G);
    velocity_products(merged_, theta_index_, w.thetad, w.links, w.tau);
    to_coordinates(merged_, theta_index_, w.tau, Cqd);
  });
  return 0.0;
}

void TreeSubsystem::coriolis(const EvalContext& /*c*/, CVecRef q, CVecRef qd, MatRef C) const {
  using AD = Eigen::AutoDiffScalar<Eigen::VectorXd>;
  const Index nt = n_theta_;
  std::vector<double> theta(static_cast<std::size_t>(nt)), thetad(static_cast<std::size_t>(nt));
  theta_of(merged_, theta_index_, q.data(), qd.data(), theta.data(), thetad.data());
  std::vector<AD> th(static_cast<std::size_t>(nt));
  for (Index k = 0; k < nt; ++k)
    th[static_cast<std::size_t>(k)] =
        AD(theta[static_cast<std::size_t>(k)], static_cast<int>(nt), static_cast<int>(k));
  std::vector<LinkState<AD>> ws(merged_.links.size());
  std::vector<AD> Mt(static_cast<std::size_t>(nt * nt));
  place(merged_, theta_index_, th.data(), ws.data());
  composite(merged_, ws.data());
  crba(merged_, theta_index_, ws.data(), Mt.data(), nt);
  // ∂M_ij/∂θ_k, zero where crba left a constant (no derivatives).
  auto dM = [&](Index i, Index j, Index k) {
    const auto& d = Mt[static_cast<std::size_t>(i + j * nt)].derivatives();
    return d.size() == nt ? d(k) : 0.0;
  };
  std::vector<double> Ct(static_cast<std::size_t>(nt * nt), 0.0);
  for (Index i = 0; i < nt; ++i) {
    for (Index j = 0; j < nt; ++j) {
      double s = 0.0;
      for (Index k = 0; k < nt; ++k)
        s += 0.5 * (dM(i, j, k) + dM(i, k, j) - dM(j, k, i)) * thetad[static_cast<std::size_t>(k)];
      Ct[static_cast<std::size_t>(i + j * nt)] = s;
    }
  }
  to_coordinates(merged_, theta_index_, Ct.data(), nt, C);  // C_q = Tᵀ C_θ T
}

void TreeSubsystem::link_pose(CVecRef q, int link, Eigen::Matrix3d& R, Eigen::Vector3d& p) const {
  R = model_.root_rotation;
  p = model_.root_translation;
  if (link < 0) return;
  const Placement& at = placement_[static_cast<std::size_t>(link)];
  if (at.link >= 0) {
    std::vector<double> theta(static_cast<std::size_t>(n_theta_));
    theta_of(merged_, theta_index_, q.data(), nullptr, theta.data(), nullptr);
    std::vector<LinkState<double>> ws(merged_.links.size());
    place(merged_, theta_index_, theta.data(), ws.data());
    R = ws[static_cast<std::size_t>(at.link)].R;
    p = ws[static_cast<std::size_t>(at.link)].p;
  }
  p += R * at.p;
  R = R * at.R;
}

void TreeSubsystem::link_poses(CVecRef q, std::vector<Eigen::Matrix3d>& R,
                               std::vector<Eigen::Vector3d>& p) const {
  std::vector<double> theta(static_cast<std::size_t>(n_theta_));
  theta_of(merged_, theta_index_, q.data(), nullptr, theta.data(), nullptr);
  std::vector<LinkState<double>> ws(merged_.links.size());
  place(merged_, theta_index_, theta.data(), ws.data());
  R.resize(model_.links.size());
  p.resize(model_.links.size());
  for (std::size_t i = 0; i < model_.links.size(); ++i) {
    const Placement& at = placement_[i];
    const Eigen::Matrix3d Rl =
        at.link < 0 ? model_.root_rotation : ws[static_cast<std::size_t>(at.link)].R;
    const Eigen::Vector3d pl =
        at.link < 0 ? model_.root_translation : ws[static_cast<std::size_t>(at.link)].p;
    R[i] = Rl * at.R;
    p[i] = pl + Rl * at.p;
  }
}

namespace {

template <class S>
M3<S> skew(const V3<S>& w) {
  M3<S> K;
  K << S(0.0), -w.z(), w.y(), w.z(), S(0.0), -w.x(), -w.y(), w.x(), S(0.0);
  return K;
}

// Link twists (ω, v_O) about the world origin and spatial accelerations (α, a_O) without gravity
// at θ̇ and θ̈ (thetadd null: θ̈ = 0, the velocity-product acceleration): the forward pass of the
// RNEA (Featherstone Table 5.1 in world coordinates) without the forces.
template <class S>
void link_motion(const Model& m, const std::vector<int>& ti, const S* thetad, const S* thetadd,
                 LinkState<S>* ws) {
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    LinkState<S>& w = ws[i];
    const int p = m.links[i].parent;
    if (p < 0) {
      w.vw.setZero();
      w.vv.setZero();
      w.aw.setZero();
      w.av.setZero();
    } else {
      w.vw = ws[p].vw;
      w.vv = ws[p].vv;
      w.aw = ws[p].aw;
      w.av = ws[p].av;
    }
    if (ti[i] < 0) continue;
    const S qd = thetad[ti[i]];
    w.aw += w.vw.cross(w.sw) * qd;
    w.av += (w.vw.cross(w.sv) + w.vv.cross(w.sw)) * qd;
    if (thetadd) {
      w.aw += w.sw * thetadd[ti[i]];
      w.av += w.sv * thetadd[ti[i]];
    }
    w.vw += w.sw * qd;
    w.vv += w.sv * qd;
  }
}

// A point p fixed in link i moves with the link's twist (ω, v_O) about the world origin:
// ṗ = v_O + ω × p, Ṙ = [ω]× R, p̈ = a_O + α × p + ω × ṗ, R̈ = ([α]× + [ω]×[ω]×) R, with (α, a_O)
// the link's spatial acceleration (link_motion). Each joint k above the link moves it by
// ∂p/∂θ_k = s_v + s_w × p, ∂R/∂θ_k = [s_w]× R (S_k = (s_w, s_v)); through θ = T q + c,
// ∂/∂q_j = Σ_k T_kj ∂/∂θ_k.
template <class S>
struct FrameMotion {
  M3<S> R, Rd, Rdd;
  V3<S> p, pd, pdd;
};

template <class S>
FrameMotion<S> frame_motion(const Model& m, const LinkState<S>* ws, int link,
                            const Eigen::Matrix3d& R_offset, const Eigen::Vector3d& x_offset) {
  M3<S> Rl = m.root_rotation.cast<S>();
  V3<S> pl = m.root_translation.cast<S>(), vw = V3<S>::Zero(), vv = V3<S>::Zero(),
        aw = V3<S>::Zero(), av = V3<S>::Zero();
  if (link >= 0) {
    const LinkState<S>& L = ws[link];
    Rl = L.R;
    pl = L.p;
    vw = L.vw;
    vv = L.vv;
    aw = L.aw;
    av = L.av;
  }
  FrameMotion<S> f;
  f.p = pl + Rl * x_offset.cast<S>();
  f.R = Rl * R_offset.cast<S>();
  f.pd = vv + vw.cross(f.p);
  f.pdd = av + aw.cross(f.p) + vw.cross(f.pd);
  const M3<S> W = skew<S>(vw);
  f.Rd = W * f.R;
  f.Rdd = (skew<S>(aw) + W * W) * f.R;
  return f;
}

// The columns ∂p/∂q_j, ∂R/∂q_j (R row-major) of the frame at (p, R) on link `link`: col(j, dp,
// dR) is called once per joint term above the link, with the coefficient applied.
template <class S, class F>
void frame_columns(const Model& m, const std::vector<int>& ti, const LinkState<S>* ws, int link,
                   const V3<S>& p, const M3<S>& R, F&& col) {
  for (int j = link; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
    const auto ju = static_cast<std::size_t>(j);
    if (ti[ju] < 0) continue;
    const V3<S> dp = ws[ju].sv + ws[ju].sw.cross(p);
    const M3<S> dR = skew<S>(ws[ju].sw) * R;
    for (const Term& t : m.links[ju].terms) col(t.coordinate, t.coefficient, dp, dR);
  }
}

}  // namespace

void TreeSubsystem::frame_state(CVecRef q, CVecRef qd, int frame_link,
                                const Eigen::Matrix3d& frame_R_offset,
                                const Eigen::Vector3d& frame_x_offset, Slot scratch,
                                FrameState& out) const {
  // The frame on the merged tree: its link there, the offset composed with the link's placement.
  int link = -1;
  Eigen::Matrix3d R_offset = frame_R_offset;
  Eigen::Vector3d x_offset = frame_x_offset;
  if (frame_link >= 0) {
    const Placement& at = placement_[static_cast<std::size_t>(frame_link)];
    link = at.link;
    R_offset = at.R * frame_R_offset;
    x_offset = at.p + at.R * frame_x_offset;
  }
  with_workspace(scratch, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_of(merged_, theta_index_, q.data(), qd.data(), w.theta, w.thetad);
    place(merged_, theta_index_, w.theta, w.links);
    link_motion<double>(merged_, theta_index_, w.thetad, nullptr, w.links);
    const FrameMotion<double> f = frame_motion(merged_, w.links, link, R_offset, x_offset);
    out.p = f.p;
    out.R = f.R;
    out.pd = f.pd;
    out.pdd = f.pdd;
    out.Rd = f.Rd;
    out.Rdd = f.Rdd;
    out.dp.setZero();
    out.dR.setZero();
    frame_columns(merged_, theta_index_, w.links, link, f.p, f.R,
                  [&](Index c, double k, const Eigen::Vector3d& dp, const Eigen::Matrix3d& dR) {
                    out.dp.col(c) += k * dp;
                    for (int r = 0; r < 9; ++r) out.dR(r, c) += k * dR(r / 3, r % 3);
                  });
  });
}

namespace {

// The dual-number workspace of the derivatives at the end of a slot (or in `own`): the links, then
// θ, θ̇, θ̈, τ (nt each), from the first 16-aligned double (Eigen aligns LinkState<Dual>).
struct DualWorkspace {
  LinkState<Dual>* links;
  Dual* theta;
  Dual* thetad;
  Dual* thetadd;
  Dual* tau;
};

DualWorkspace dual_workspace(Slot slot, Index slot_size, std::size_t nl, Index nt,
                             std::vector<double>& own) {
  const Index need = tangent_workspace_doubles(nl, nt);
  double* base = nullptr;
  if (static_cast<Index>(slot.size()) >= slot_size) {
    base = slot.data() + (slot_size - need);
  } else {
    own.resize(static_cast<std::size_t>(need));
    base = own.data();
  }
  if (reinterpret_cast<std::uintptr_t>(base) % 16 != 0) ++base;  // (doubles are 8-aligned)
  DualWorkspace w{};
  w.links = reinterpret_cast<LinkState<Dual>*>(base);
  for (std::size_t i = 0; i < nl; ++i) new (&w.links[i]) LinkState<Dual>;
  w.theta = reinterpret_cast<Dual*>(base + static_cast<Index>(nl) * kDualLinkDoubles);
  for (Index k = 0; k < 4 * nt; ++k) new (&w.theta[k]) Dual;
  w.thetad = w.theta + nt;
  w.thetadd = w.thetad + nt;
  w.tau = w.thetadd + nt;
  return w;
}

// The forward workspace at the start of a full slot (empty without one: a buffer of its own).
Slot forward_part(Slot slot, Index slot_size) {
  return static_cast<Index>(slot.size()) >= slot_size ? slot : Slot();
}

// θ, θ̇ seeded with dθ = T dq, dθ̇ = T dq̇; θ̈ = T q̈ held (no tangent).
void seed_duals(const Model& m, const std::vector<int>& ti, CVecRef q, CVecRef qd, CVecRef qdd,
                CVecRef dq, CVecRef dqd, const DualWorkspace& w) {
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (ti[i] < 0) continue;
    const Link& L = m.links[i];
    double v = L.offset, dv = 0.0, s = 0.0, ds = 0.0, a = 0.0;
    for (const Term& t : L.terms) {
      v += t.coefficient * q(t.coordinate);
      dv += t.coefficient * dq(t.coordinate);
      s += t.coefficient * qd(t.coordinate);
      ds += t.coefficient * dqd(t.coordinate);
      a += t.coefficient * qdd(t.coordinate);
    }
    const auto k = static_cast<std::size_t>(ti[i]);
    w.theta[k] = dual(v, dv);
    w.thetad[k] = dual(s, ds);
    w.thetadd[k] = dual(a, 0.0);
  }
}

// The link poses, axes and inertias on dual numbers at θ (w.theta). Along a direction that moves
// no joint (dθ = T dq = 0: a direction of q̇) they have no tangent: placed on doubles in `flat`
// (the slot's forward workspace, or a buffer of its own without one) and lifted, the same values
// with zero tangents, at a fraction of the dual numbers' cost.
void place_duals(const Model& m, const std::vector<int>& ti, Index nt, const DualWorkspace& w,
                 Slot flat) {
  bool still = true;
  for (Index k = 0; k < nt && still; ++k) still = w.theta[k].derivatives()(0) == 0.0;
  if (!still) {
    place(m, ti, w.theta, w.links);
    return;
  }
  with_workspace(flat, workspace_doubles(m.links.size(), nt), m.links.size(), nt, [&](Workspace f) {
    for (Index k = 0; k < nt; ++k) f.theta[k] = w.theta[k].value();
    place(m, ti, f.theta, f.links);
    for (std::size_t i = 0; i < m.links.size(); ++i) {
      const LinkState<double>& a = f.links[i];
      LinkState<Dual>& b = w.links[i];
      b.R = a.R.cast<Dual>();
      b.p = a.p.cast<Dual>();
      b.sw = a.sw.cast<Dual>();
      b.sv = a.sv.cast<Dual>();
      b.m_own = Dual(a.m_own);
      b.h_own = a.h_own.cast<Dual>();
      b.I_own = a.I_own.cast<Dual>();
    }
  });
}

double value_of(const Dual& x) { return x.value(); }
double tangent_of(const Dual& x) { return x.derivatives().size() > 0 ? x.derivatives()(0) : 0.0; }

template <int R, int C>
void split(const Eigen::Matrix<Dual, R, C>& x, Eigen::Matrix<double, R, C>& v,
           Eigen::Matrix<double, R, C>& d) {
  v = x.unaryExpr([](const Dual& e) { return value_of(e); });
  d = x.unaryExpr([](const Dual& e) { return tangent_of(e); });
}

}  // namespace

// The same pass as frame_state() with θ̈ = T q̈ on dual numbers seeded with (T dq, T dq̇): exact
// directional derivatives (forward-mode automatic differentiation, Griewank & Walther 2008,
// ch. 3) of the frame's pose, twist, acceleration at q̈ and columns.
void TreeSubsystem::frame_state_tangent(CVecRef q, CVecRef qd, CVecRef qdd, CVecRef dq, CVecRef dqd,
                                        int frame_link, const Eigen::Matrix3d& frame_R_offset,
                                        const Eigen::Vector3d& frame_x_offset, Slot scratch,
                                        FrameState& value, FrameState& tangent) const {
  int link = -1;
  Eigen::Matrix3d R_offset = frame_R_offset;
  Eigen::Vector3d x_offset = frame_x_offset;
  if (frame_link >= 0) {
    const Placement& at = placement_[static_cast<std::size_t>(frame_link)];
    link = at.link;
    R_offset = at.R * frame_R_offset;
    x_offset = at.p + at.R * frame_x_offset;
  }
  std::vector<double> own;
  const DualWorkspace w = dual_workspace(scratch, slot_size_, merged_.links.size(), n_theta_, own);
  seed_duals(merged_, theta_index_, q, qd, qdd, dq, dqd, w);
  place_duals(merged_, theta_index_, n_theta_, w, forward_part(scratch, slot_size_));
  link_motion<Dual>(merged_, theta_index_, w.thetad, w.thetadd, w.links);
  const FrameMotion<Dual> f = frame_motion(merged_, w.links, link, R_offset, x_offset);
  split(f.p, value.p, tangent.p);
  split(f.R, value.R, tangent.R);
  split(f.pd, value.pd, tangent.pd);
  split(f.Rd, value.Rd, tangent.Rd);
  split(f.pdd, value.pdd, tangent.pdd);
  split(f.Rdd, value.Rdd, tangent.Rdd);
  value.dp.setZero();
  value.dR.setZero();
  tangent.dp.setZero();
  tangent.dR.setZero();
  frame_columns(merged_, theta_index_, w.links, link, f.p, f.R,
                [&](Index c, double k, const V3<Dual>& dp, const M3<Dual>& dR) {
                  for (int r = 0; r < 3; ++r) {
                    value.dp(r, c) += k * value_of(dp(r));
                    tangent.dp(r, c) += k * tangent_of(dp(r));
                  }
                  for (int r = 0; r < 9; ++r) {
                    value.dR(r, c) += k * value_of(dR(r / 3, r % 3));
                    tangent.dR(r, c) += k * tangent_of(dR(r / 3, r % 3));
                  }
                });
}

// dID = Tᵀ dτ_θ with τ_θ = RNEA(θ, θ̇, θ̈) run once on dual numbers seeded with dθ = T dq,
// dθ̇ = T dq̇ (θ̈ = T q̈ held): the exact directional derivative (forward-mode automatic
// differentiation, Griewank & Walther 2008, ch. 3) of the inverse dynamics at fixed q̈.
bool TreeSubsystem::inverse_dynamics_tangent(const EvalContext& c, CVecRef q, CVecRef qd,
                                             CVecRef qdd, CVecRef dq, CVecRef dqd,
                                             VecRef dID) const {
  const std::size_t nl = merged_.links.size();
  std::vector<double> own;
  const DualWorkspace w = dual_workspace(c.slot, slot_size_, nl, n_theta_, own);
  seed_duals(merged_, theta_index_, q, qd, qdd, dq, dqd, w);
  place_duals(merged_, theta_index_, n_theta_, w, forward_part(c.slot, slot_size_));
  inverse_dynamics(merged_, theta_index_, w.thetad, w.thetadd, w.links, w.tau);
  dID.setZero();
  for (std::size_t i = 0; i < nl; ++i) {
    if (theta_index_[i] < 0) continue;
    const double d = tangent_of(w.tau[theta_index_[i]]);
    for (const Term& t : merged_.links[i].terms) dID(t.coordinate) += t.coefficient * d;
  }
  return true;
}

std::shared_ptr<const TreeSubsystem> make_subsystem(Model model) {
  return std::make_shared<TreeSubsystem>(std::move(model));
}

}  // namespace ukdyn::tree
