// The recursive rigid-body algorithms over a tree (ukdyn/tree/tree.hpp): placement of the links,
// the composite-rigid-body algorithm (CRBA, Featherstone 2008 §6.2, Table 6.2) and the recursive
// Newton–Euler algorithm (RNEA, §5.3, Table 5.1), in world coordinates about the world origin
// (§2.9). The algorithms are templates on the scalar so that the same code runs on doubles (the
// hot path, workspace in the caller's slot) and on dual numbers (∂M/∂θ for the
// Christoffel matrix).
#include "ukdyn/tree/tree.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <new>
#include <set>
#include <unsupported/Eigen/AutoDiff>

#include "core/lane_dual.hpp"
#include "tree/dual.hpp"
#include "tree/sin_cos.hpp"

namespace ukdyn::tree {

namespace {

template <class S>
using V3 = Eigen::Matrix<S, 3, 1>;
template <class S>
using M3 = Eigen::Matrix<S, 3, 3>;

// Joint variables of a joint: a ball joint has four (its quaternion), a revolute or prismatic
// joint one, a fixed joint none (floating joints are split into three prismatic joints and a
// ball joint before the passes: TreeSubsystem's constructor).
int variables(JointType t) {
  if (t == JointType::fixed) return 0;
  return t == JointType::ball ? 4 : 1;
}

// What one evaluation computes per link (the workspace).
//
// Motion and force vectors are those of Featherstone's absolute coordinates (§2.9) extended by one
// component for the quaternion joints. R(u), the homogeneous quaternion matrix the symbolic chain
// uses, is |u|² times a rotation, so a link below a ball joint is placed by a similarity (a
// rotation and a scale); its velocity field is v(x) = v_O + ω × x + λ x (λ: the rate of the log of
// the scale), a motion (ω, λ, v_O), and a force (n_O, e, f) pairs with it as ω·n_O + λ e + v_O·f
// (e = Σ x·f, the virial). In trees without ball joints λ = 0 and every pass is the rigid one.
template <class S>
struct LinkState {
  M3<S> R;  // link frame → world (|u|² times a rotation per ball joint above)
  V3<S> p;  // link frame origin in the world
  // Motion axes S_k = (sw, sl, sv) about the world origin, one per joint variable.
  V3<S> sw[4], sv[4];
  S sl[4];
  S sc, qs;  // the scale of R (Π |u|² of the ball joints at or above); a ball joint's 2 / |u|²
  // Spatial inertia about the world origin as (mass m, first moment h = m c, rotational inertia
  // Ī = I_c + m(|c|² 1 − c cᵀ), k = m |c|²): the link's own and the composite of its subtree.
  S m_own, m, k_own, k;
  V3<S> h_own, h, c;     // c: the CoM in the world
  M3<S> I_own, I, Ic;    // Ic: the link's inertia about its CoM in world axes
  V3<S> vw, vv, aw, av;  // velocity and acceleration (RNEA)
  S vl, al, lj;          // their λ parts; lj: a ball joint's own λ
  V3<S> fn, ff;          // force of the subtree (RNEA)
  S fe;
  // The terms of the symbolic body rate (rate_scale_terms): Σ Ic ω and Σ Ic of the subtree, Σ λ ω
  // of the ball joints at or above, Σ λ (H + Ir ω) of those at or below.
  M3<S> Ir;
  V3<S> H, Y, Z;
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

// A revolute joint's link frame R = Rj R_a(θ) and its axis Rj a in the world. About a coordinate
// axis e_k (URDF's usual <axis xyz="0 0 1"/>: every joint of the Panda and the UR5e, a platform's
// yaw) R_a(θ) turns e_i to c e_i + s e_j and e_j to −s e_i + c e_j ((k, i, j) cyclic) and keeps
// e_k, so R's columns are those of Rj mixed in pairs and the axis is Rj's column k: neither
// Rodrigues' matrix nor the 3 × 3 product is formed.
template <class S, int K>
void turn_about(const M3<S>& Rj, const S& c, const S& s, LinkState<S>& w) {
  constexpr int i = (K + 1) % 3, j = (K + 2) % 3;
  w.R.col(i) = c * Rj.col(i) + s * Rj.col(j);
  w.R.col(j) = c * Rj.col(j) - s * Rj.col(i);
  w.R.col(K) = Rj.col(K);
  w.sw[0] = Rj.col(K);
}

template <class S>
void turn_about_axis(int k, const M3<S>& Rj, const S& th, LinkState<S>& w) {
  using std::cos;
  using std::sin;
  const S c = cos(th), s = sin(th);
  if (k == 2) {
    turn_about<S, 2>(Rj, c, s, w);
  } else if (k == 0) {
    turn_about<S, 0>(Rj, c, s, w);
  } else {
    turn_about<S, 1>(Rj, c, s, w);
  }
}

// turn_about_axis on doubles for the rigid passes: cos θ and sin θ from trig::sin_cos (one
// reduction and two polynomials, no call into the C library; within 1 ulp of std::cos, std::sin).
void turn_about_axis_rigid(int k, const Eigen::Matrix3d& Rj, double th, LinkState<double>& w) {
  double s = 0.0, c = 0.0;
  trig::sin_cos(th, s, c);
  if (k == 2) {
    turn_about<double, 2>(Rj, c, s, w);
  } else if (k == 0) {
    turn_about<double, 0>(Rj, c, s, w);
  } else {
    turn_about<double, 1>(Rj, c, s, w);
  }
}

template <class S>
void place_revolute(const Eigen::Vector3d& a, const M3<S>& Rj, const S& th, LinkState<S>& w) {
  const int k = a(2) == 1.0 ? 2 : a(0) == 1.0 ? 0 : a(1) == 1.0 ? 1 : -1;
  if (k < 0 || a((k + 1) % 3) != 0.0 || a((k + 2) % 3) != 0.0) {
    w.R = Rj * axis_rotation<S>(a, th);
    w.sw[0] = Rj * a.cast<S>();
    return;
  }
  turn_about_axis(k, Rj, th, w);
}

// A ball joint at pj with joint frame Rj (scale sc) and quaternion u = (w, x, y, z): the link's
// R = Rj R(u), R(u) as the symbolic chain's quaternion_rotation (symbolic/free_body.cpp), and the
// motion axes of its four variables: the rotation ω = 2 G(u) u̇ / |u|² in the joint frame
// (G(u) = [−x w −z y; −y z w −x; −z −y x w], the space-frame rate matrix: R(u) E(u) = |u|² G(u)
// with the body-frame E of free_body.hpp), turned to the world by Rj / sc, and the scale's rate
// λ = 2 u·u̇ / |u|², both about pj.
template <class S>
void place_ball(const M3<S>& Rj, const V3<S>& pj, const S& sc, const S* u, LinkState<S>& w) {
  const S qw = u[0], qx = u[1], qy = u[2], qz = u[3];
  M3<S> Ru;
  Ru(0, 0) = qw * qw + qx * qx - qy * qy - qz * qz;
  Ru(0, 1) = S(2.0) * (qx * qy - qw * qz);
  Ru(0, 2) = S(2.0) * (qx * qz + qw * qy);
  Ru(1, 0) = S(2.0) * (qx * qy + qw * qz);
  Ru(1, 1) = qw * qw - qx * qx + qy * qy - qz * qz;
  Ru(1, 2) = S(2.0) * (qy * qz - qw * qx);
  Ru(2, 0) = S(2.0) * (qx * qz - qw * qy);
  Ru(2, 1) = S(2.0) * (qy * qz + qw * qx);
  Ru(2, 2) = qw * qw - qx * qx - qy * qy + qz * qz;
  const S n2 = qw * qw + qx * qx + qy * qy + qz * qz;
  w.R = Rj * Ru;
  w.p = pj;
  w.qs = S(2.0) / n2;
  w.sc = sc * n2;
  const V3<S> g[4] = {V3<S>(S(-qx), S(-qy), S(-qz)), V3<S>(qw, qz, S(-qy)), V3<S>(S(-qz), qw, qx),
                      V3<S>(qy, S(-qx), qw)};
  const M3<S> Rw = Rj * (w.qs / sc);
  for (int k = 0; k < 4; ++k) {
    w.sw[k] = Rw * g[k];
    w.sl[k] = u[k] * w.qs;
    w.sv[k] = pj.cross(w.sw[k]) - pj * w.sl[k];
  }
}

// A link's inertia about its CoM in world axes, Ic = R I Rᵀ, and about the world origin,
// Ī = Ic + m (|c|² 1 − c cᵀ) (the parallel-axis theorem): both symmetric, so each entry above
// the diagonal is formed once and mirrored.
template <class S>
void own_inertia(const M3<S>& R, const Eigen::Matrix3d& I, const S& m, const V3<S>& c, M3<S>& Ic,
                 M3<S>& Io) {
  const M3<S> T = R * I.cast<S>();
  const S c2 = dot3(c, c);
  for (int a = 0; a < 3; ++a) {
    for (int b = a; b < 3; ++b) {
      Ic(a, b) = T(a, 0) * R(b, 0) + T(a, 1) * R(b, 1) + T(a, 2) * R(b, 2);
      Io(a, b) = Ic(a, b) - m * c(a) * c(b);
      if (a == b) Io(a, b) += m * c2;
      Ic(b, a) = Ic(a, b);
      Io(b, a) = Io(a, b);
    }
  }
}

// Link poses, motion axes and own inertias at the joint variables theta (Featherstone §4.1: the
// forward pass of placement, parent before child). quat: the tree has ball joints (scales).
template <class S>
void place(const Model& m, const std::vector<int>& ti, bool quat, const S* theta,
           LinkState<S>* ws) {
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const Link& L = m.links[i];
    LinkState<S>& w = ws[i];
    M3<S> Rp;
    V3<S> pp;
    S sc(1.0);
    if (L.parent < 0) {
      Rp = m.root_rotation.cast<S>();
      pp = m.root_translation.cast<S>();
    } else {
      Rp = ws[L.parent].R;
      pp = ws[L.parent].p;
      if (quat) sc = ws[L.parent].sc;
    }
    const M3<S> Rj = Rp * L.origin_rotation.cast<S>();
    const V3<S> pj = pp + Rp * L.origin_translation.cast<S>();
    w.sc = sc;
    w.sl[0] = S(0.0);
    if (L.type == JointType::revolute) {
      place_revolute<S>(L.axis, Rj, theta[ti[i]], w);
      w.p = pj;
      if (quat) w.sw[0] /= sc;      // the axis of the rotation part of Rj
      w.sv[0] = pj.cross(w.sw[0]);  // v_O = ω × (0 − p_j) = p_j × z
    } else if (L.type == JointType::prismatic) {
      w.R = Rj;
      w.sw[0].setZero();
      w.sv[0] = Rj * L.axis.cast<S>();
      w.p = pj + w.sv[0] * theta[ti[i]];
    } else if (L.type == JointType::ball) {
      place_ball<S>(Rj, pj, sc, theta + ti[i], w);
    } else {
      w.R = Rj;
      w.p = pj;
    }
    if (L.mass == 0.0 && L.inertia.isZero(0.0)) {  // a massless frame (flange, tool0)
      w.m_own = S(0.0);
      w.k_own = S(0.0);
      w.h_own.setZero();
      w.I_own.setZero();
      w.Ic.setZero();
      w.c = w.p;
      continue;
    }
    const V3<S> c = w.p + w.R * L.com.cast<S>();
    w.c = c;
    w.m_own = S(L.mass);
    w.h_own = c * w.m_own;
    w.k_own = w.m_own * dot3(c, c);
    own_inertia(w.R, L.inertia, w.m_own, c, w.Ic, w.I_own);
  }
}

// (n, e, f) = I (w, l, v) for the spatial inertia (m, h, Ī, k) about the world origin (the
// gradient of the kinetic energy ½ m |v + ω × c + λ c|² + ½ ωᵀ I_c ω): n = Ī ω + h × v,
// f = m v − h × ω + λ h, e = h · v + k λ.
template <class S>
inline void apply_inertia(const S& m, const V3<S>& h, const M3<S>& I, const V3<S>& w,
                          const V3<S>& v, V3<S>& n, V3<S>& f) {
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
    ws[i].k = ws[i].k_own;
  }
  for (std::size_t i = n; i-- > 0;) {
    const int p = m.links[i].parent;
    if (p < 0) continue;
    ws[p].m += ws[i].m;
    ws[p].h += ws[i].h;
    ws[p].I += ws[i].I;
    ws[p].k += ws[i].k;
  }
}

// ⟨S_k of link w, (n, e, f)⟩ = sw · n + sl e + sv · f.
template <class S>
S pair(const LinkState<S>& w, int k, const V3<S>& n, const S& e, const V3<S>& f, bool quat) {
  const S r = dot3(w.sw[k], n) + dot3(w.sv[k], f);
  return quat ? S(r + w.sl[k] * e) : r;
}

// crba below without ball joints: every movable link has one joint variable and no scale, so
// (n, f) = I^c_i S_i is paired with each ancestor's single axis directly (the same sums in the
// same order as pair() with quat false).
template <class S>
void crba_rigid(const Model& m, const std::vector<int>& ti, const LinkState<S>* ws, S* Mt,
                Index nt) {  // nt: Mt's leading dimension
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const int a = ti[i];
    if (a < 0) continue;
    const LinkState<S>& w = ws[i];
    V3<S> n, f;
    apply_inertia(w.m, w.h, w.I, w.sw[0], w.sv[0], n, f);
    Mt[a + a * nt] = dot3(w.sw[0], n) + dot3(w.sv[0], f);
    for (int j = m.links[i].parent; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
      const LinkState<S>& u = ws[j];
      const int b = ti[static_cast<std::size_t>(j)];
      if (b < 0) continue;
      const S v = dot3(u.sw[0], n) + dot3(u.sv[0], f);
      Mt[a + b * nt] = v;
      Mt[b + a * nt] = v;
    }
  }
}

// M_θ (nt × nt, column-major in Mt) from the composite inertias: M_ii = S_iᵀ I^c_i S_i and, for
// each ancestor j of i, M_ij = M_ji = S_jᵀ (I^c_i S_i) (Featherstone Table 6.2), one row and
// column per joint variable. ld: Mt's leading dimension (0: nt).
template <class S>
void crba(const Model& m, const std::vector<int>& ti, bool quat, const LinkState<S>* ws, S* Mt,
          Index nt, Index ld = 0) {
  if (ld == 0) ld = nt;
  for (Index j = 0; j < nt; ++j)
    for (Index k = 0; k < nt; ++k) Mt[k + j * ld] = S(0.0);
  if (!quat) {
    crba_rigid(m, ti, ws, Mt, ld);
    return;
  }
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (ti[i] < 0) continue;
    const LinkState<S>& w = ws[i];
    const int nv = variables(m.links[i].type);
    for (int ka = 0; ka < nv; ++ka) {
      const int a = ti[i] + ka;
      V3<S> n, f;
      apply_inertia(w.m, w.h, w.I, w.sw[ka], w.sv[ka], n, f);
      S e(0.0);
      if (quat) {
        f += w.h * w.sl[ka];
        e = dot3(w.h, w.sv[ka]) + w.k * w.sl[ka];
      }
      for (int kb = 0; kb < nv; ++kb) Mt[a + (ti[i] + kb) * ld] = pair(w, kb, n, e, f, quat);
      for (int j = m.links[i].parent; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
        const auto ju = static_cast<std::size_t>(j);
        if (ti[ju] < 0) continue;
        for (int kb = 0; kb < variables(m.links[ju].type); ++kb) {
          const int b = ti[ju] + kb;
          const S v = pair(ws[ju], kb, n, e, f, quat);
          Mt[a + b * ld] = v;
          Mt[b + a * ld] = v;
        }
      }
    }
  }
}

// The link's velocity and acceleration from its parent's (already in w) and its joint's motion
// (Featherstone Table 5.1 in world coordinates): V = V_p + Σ S_k θ̇_k, A = A_p + Σ S_k θ̈_k +
// [V_p, S_k] θ̇_k (Ṡ_k = V × S_k for an axis fixed in the parent) with the bracket of the
// similarity motions, [(ω1, λ1, v1), (ω2, λ2, v2)] = (ω1 × ω2, 0, ω1 × v2 + λ1 v2 − ω2 × v1 −
// λ2 v1); a ball joint adds the rate of its own axes, d/dt (2 G(u) / |u|², 2 u / |u|²) u̇ =
// (−λ ω, 2 |u̇|² / |u|² − λ²) about its origin (G(u̇) u̇ = 0). thetadd null: θ̈ = 0.
template <class S>
void joint_motion(const Link& L, int first, bool quat, const S* thetad, const S* thetadd,
                  LinkState<S>& w) {
  if (!quat) {  // one joint variable, no scale: the loop below with nv = 1, in the same order
    const S qd = thetad[first];
    w.aw += w.vw.cross(w.sw[0]) * qd;
    w.av += (w.vw.cross(w.sv[0]) + w.vv.cross(w.sw[0])) * qd;
    if (thetadd) {
      w.aw += w.sw[0] * thetadd[first];
      w.av += w.sv[0] * thetadd[first];
    }
    w.vw += w.sw[0] * qd;
    w.vv += w.sv[0] * qd;
    return;
  }
  const int nv = variables(L.type);
  V3<S> jw = V3<S>::Zero(), jv = V3<S>::Zero();
  S jl(0.0), ud2(0.0);
  for (int k = 0; k < nv; ++k) {
    const S qd = thetad[first + k];
    w.aw += w.vw.cross(w.sw[k]) * qd;
    w.av += (w.vw.cross(w.sv[k]) + w.vv.cross(w.sw[k])) * qd;
    if (quat) {
      w.av += (w.sv[k] * w.vl - w.vv * w.sl[k]) * qd;
      jl += w.sl[k] * qd;
      ud2 += qd * qd;
    }
    if (thetadd) {
      const S qdd = thetadd[first + k];
      w.aw += w.sw[k] * qdd;
      w.av += w.sv[k] * qdd;
      if (quat) w.al += w.sl[k] * qdd;
    }
    jw += w.sw[k] * qd;
    jv += w.sv[k] * qd;
  }
  if (L.type == JointType::ball) {
    const V3<S> aw = -jw * jl;
    const S al = ud2 * w.qs - jl * jl;
    w.aw += aw;
    w.al += al;
    w.av += w.p.cross(aw) - w.p * al;
    w.lj = jl;
  }
  w.vw += jw;
  w.vv += jv;
  w.vl += jl;
}

// Link velocities and accelerations, parent before child: a_0 = (0, 0, a0) at the root (−g for
// the inverse dynamics, §5.3; 0 for the velocity products).
template <class S>
void link_motion(const Model& m, const std::vector<int>& ti, bool quat, const S* thetad,
                 const S* thetadd, const V3<S>& a0, LinkState<S>* ws) {
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    LinkState<S>& w = ws[i];
    const int p = m.links[i].parent;
    if (p < 0) {
      w.vw.setZero();
      w.vv.setZero();
      w.aw.setZero();
      w.av = a0;
      w.vl = S(0.0);
      w.al = S(0.0);
    } else {
      w.vw = ws[p].vw;
      w.vv = ws[p].vv;
      w.aw = ws[p].aw;
      w.av = ws[p].av;
      w.vl = ws[p].vl;
      w.al = ws[p].al;
    }
    if (ti[i] >= 0) joint_motion(m.links[i], ti[i], quat, thetad, thetadd, w);
  }
}

// The link's own force f_i = I_i a_i + v_i ×* I_i v_i (Newton–Euler). With scales (quat): the
// CoM's acceleration c̈ = a_O + α × c + λ̇ c + ω × ċ + λ ċ (ċ = v_O + ω × c + λ c), f = m c̈,
// n = c × f + I_c α + ω × I_c ω, e = c · f: Lagrange's equations of ½ m |ċ|² + ½ ωᵀ I_c ω.
template <class S>
void link_force(const Link& L, bool quat, LinkState<S>& w) {
  w.fe = S(0.0);
  if (L.mass == 0.0 && L.inertia.isZero(0.0)) {  // a massless frame: no force of its own
    w.fn.setZero();
    w.ff.setZero();
    return;
  }
  if (quat) {
    const V3<S> cd = w.vv + w.vw.cross(w.c) + w.c * w.vl;
    const V3<S> cdd = w.av + w.aw.cross(w.c) + w.c * w.al + w.vw.cross(cd) + cd * w.vl;
    w.ff = cdd * w.m_own;
    w.fn = w.c.cross(w.ff) + w.Ic * w.aw + w.vw.cross(V3<S>(w.Ic * w.vw));
    w.fe = dot3(w.c, w.ff);
    return;
  }
  V3<S> n1, f1, n2, f2;
  apply_inertia(w.m_own, w.h_own, w.I_own, w.vw, w.vv, n1, f1);  // momentum I v
  apply_inertia(w.m_own, w.h_own, w.I_own, w.aw, w.av, n2, f2);  // I a
  // (ω, v) ×* (n, f) = (ω × n + v × f, ω × f)
  w.fn = n2 + w.vw.cross(n1) + w.vv.cross(f1);
  w.ff = f2 + w.vw.cross(f1);
}

// The symbolic chain's body rate below a ball joint is ω_b = R(u)ᵀ ω_joint + 2 E(u) u̇ (chain.cpp),
// which off |u| = 1 is not the rate of the rotation: d/dρ of it along the joint's radial direction
// (ρ = ln |u|) is 2 ω_k (the rate of the link on the joint k, in the body's axes) where the
// rotation's is 0. On |u| = 1 the two agree for every u̇, so their kinetic energies differ by ΔT
// with ΔT = ∂ΔT/∂q̇ = 0 there and ∂ΔT/∂ρ_k = 2 ω_k · Σ_{b below k} I_b ω_b; Lagrange's equations
// of ΔT add, with λ_k = 2 ρ̇_k:
//   Δτ_i = S_iᵀ [Σ_{k at or below i} λ_k (H_k + Ir_k ω_k) + Ir_i Σ_{k above i} λ_k ω_k]
//          − [q_i in k] (2 u_i / |u|²) ω_k · H_k,
// H_k = Σ I_b ω_b and Ir_k = Σ I_b over the subtree of k (the derivation in
// docs/tree-algorithms.md, "Quaternion joints"). Run after link_motion, on the velocities.
template <class S>
void rate_scale_terms(const Model& m, const std::vector<int>& ti, LinkState<S>* ws, S* tau) {
  const std::size_t n = m.links.size();
  for (std::size_t i = 0; i < n; ++i) {
    LinkState<S>& w = ws[i];
    const int p = m.links[i].parent;
    const bool ball = m.links[i].type == JointType::ball;
    w.Y = p < 0 ? V3<S>::Zero() : ws[p].Y;
    if (ball) w.Y += w.vw * w.lj;
    w.H = w.Ic * w.vw;
    w.Ir = w.Ic;
    w.Z.setZero();
  }
  for (std::size_t i = n; i-- > 0;) {
    LinkState<S>& w = ws[i];
    const Link& L = m.links[i];
    const int p = L.parent;
    if (L.type == JointType::ball) w.Z += (w.H + w.Ir * w.vw) * w.lj;
    if (ti[i] >= 0) {
      V3<S> t = w.Z;
      if (p >= 0) t += w.Ir * ws[p].Y;
      const S wh = dot3(w.vw, w.H);
      for (int k = 0; k < variables(L.type); ++k) {
        tau[ti[i] + k] += dot3(w.sw[k], t);
        if (L.type == JointType::ball) tau[ti[i] + k] -= w.sl[k] * wh;
      }
    }
    if (p >= 0) {
      ws[p].H += w.H;
      ws[p].Ir += w.Ir;
      ws[p].Z += w.Z;
    }
  }
}

// τ_i = S_iᵀ Σ_subtree f, the forces summed into the parents (the RNEA's backward pass).
template <class S>
void joint_forces(const Model& m, const std::vector<int>& ti, bool quat, LinkState<S>* ws, S* tau) {
  for (std::size_t i = m.links.size(); i-- > 0;) {
    LinkState<S>& w = ws[i];
    if (ti[i] >= 0) {
      for (int k = 0; k < variables(m.links[i].type); ++k)
        tau[ti[i] + k] = pair(w, k, w.fn, w.fe, w.ff, quat);
    }
    const int p = m.links[i].parent;
    if (p >= 0) {
      ws[p].fn += w.fn;
      ws[p].ff += w.ff;
      ws[p].fe += w.fe;
    }
  }
}

// The inverse dynamics τ = M(θ) θ̈ + C(θ, θ̇) θ̇ + G(θ) by the RNEA (Featherstone Table 5.1 in
// world coordinates), gravity as the fictitious base acceleration a_0 = (0, −g) (§5.3); thetadd
// null and gravity false: C(θ, θ̇) θ̇, the velocity products. Run on dual numbers it gives the
// exact directional derivatives of τ (the derivatives of the dynamics, docs/derivatives.md).
template <class S>
void inverse_dynamics(const Model& m, const std::vector<int>& ti, bool quat, const S* thetad,
                      const S* thetadd, bool gravity, LinkState<S>* ws, S* tau) {
  const V3<S> a0 = gravity ? V3<S>(-m.gravity.cast<S>()) : V3<S>(V3<S>::Zero());
  link_motion(m, ti, quat, thetad, thetadd, a0, ws);
  for (std::size_t i = 0; i < m.links.size(); ++i) link_force(m.links[i], quat, ws[i]);
  joint_forces(m, ti, quat, ws, tau);
  if (quat) rate_scale_terms(m, ti, ws, tau);
}

// G_θ from the composite inertias: the force I^c_i (0, −g) of each subtree held against gravity,
// G_i = S_iᵀ (−h^c_i × g, −h^c_i · g, −m^c_i g).
template <class S>
void gravity_forces(const Model& m, const std::vector<int>& ti, bool quat, const LinkState<S>* ws,
                    S* G) {
  const V3<S> g = m.gravity.cast<S>();
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (ti[i] < 0) continue;
    const LinkState<S>& w = ws[i];
    const V3<S> n = -w.h.cross(g), f = -g * w.m;
    const S e = -dot3(w.h, g);
    for (int k = 0; k < variables(m.links[i].type); ++k) G[ti[i] + k] = pair(w, k, n, e, f, quat);
  }
}

bool finite3(const Eigen::Vector3d& v) { return v.allFinite(); }

}  // namespace

// ------------------------------------------------------------------------------ the rigid path

// What the forward passes of a tree without ball joints know of each link before any call
// (TreeSubsystem's constructor): where its joint frame's columns come from, which coordinate
// axis its joint turns or slides along, whether it has mass, and its movable ancestors.
struct LinkPlan {
  // The fixed rotation of the joint frame (origin_rotation, merged): its column c is
  // sign[c] e_perm[c] (a signed permutation: identity, URDF's rpy of ±π/2 and π), or general.
  bool permutation = false;
  int perm[3] = {0, 1, 2};
  double sign[3] = {1.0, 1.0, 1.0};
  int axis = -1;                // the joint's axis is e_axis of the joint frame (−1: any other)
  int terms = 0, term[3] = {};  // the nonzero entries of origin_translation
  bool massless = false;        // no mass and no inertia (flange, tool0, a platform's x, y)
  // The inertia about the CoM as F Fᵀ, F lower triangular (its Cholesky factor; false when the
  // inertia is not positive definite; Golub & Van Loan, Matrix Computations, 4th ed., §4.2):
  // f = F00 F10 F20 F11 F21 F22.
  bool factored = false;
  double f[6] = {};
  std::size_t ancestors = 0, ancestors_end = 0;  // ForwardPlan::ancestors: the movable ones
};
struct ForwardPlan {
  std::vector<LinkPlan> links;
  std::vector<std::pair<std::size_t, int>> ancestors;  // (link, joint variable), nearest first
  bool every_pair = false;  // each joint variable's link has every earlier one as an ancestor
  bool identity = false;    // θ = q (identity_map)
  bool serial = false;      // link i's parent is i − 1 (an unbranched chain from link 0)
};

namespace {

// A rotation within round-off of a signed permutation made exactly that permutation: the URDF's
// rpy of ±π/2 and π give entries of cos(π/2) = 6.1e-17 and sin(π) = 1.2e-16 (the double nearest
// π/2 is not π/2) where the rotation meant has exact zeros. 1e-15 is 4.5 ε: the round-off of a
// few products of rotations, far below any rotation a robot file means. Returns whether it did.
bool snap_permutation(Eigen::Matrix3d& R) {
  constexpr double tol = 1e-15;
  Eigen::Matrix3d P = Eigen::Matrix3d::Zero();
  int rows_used = 0;
  for (int c = 0; c < 3; ++c) {
    int at = -1;
    for (int r = 0; r < 3; ++r) {
      if (std::abs(std::abs(R(r, c)) - 1.0) <= tol) {
        if (at >= 0) return false;
        at = r;
      } else if (!(std::abs(R(r, c)) <= tol)) {
        return false;
      }
    }
    if (at < 0 || (rows_used & (1 << at)) != 0) return false;
    rows_used |= 1 << at;
    P(at, c) = R(at, c) > 0.0 ? 1.0 : -1.0;
  }
  R = P;
  return true;
}

LinkPlan link_plan(const Link& L) {
  LinkPlan p;
  const Eigen::Matrix3d& R = L.origin_rotation;
  p.permutation = true;
  for (int c = 0; c < 3 && p.permutation; ++c) {
    int nonzero = 0;
    for (int r = 0; r < 3; ++r) {
      if (R(r, c) == 0.0) continue;
      ++nonzero;
      p.perm[c] = r;
      p.sign[c] = R(r, c);
    }
    p.permutation = nonzero == 1 && std::abs(p.sign[c]) == 1.0;
  }
  if (!p.permutation) p = LinkPlan{};
  for (int k = 0; k < 3; ++k) {
    if (L.axis(k) == 1.0 && L.axis((k + 1) % 3) == 0.0 && L.axis((k + 2) % 3) == 0.0) p.axis = k;
    if (L.origin_translation(k) != 0.0) p.term[p.terms++] = k;
  }
  p.massless = L.mass == 0.0 && L.inertia.isZero(0.0);
  const Eigen::LLT<Eigen::Matrix3d> llt(L.inertia);
  if (!p.massless && L.inertia == L.inertia.transpose() && llt.info() == Eigen::Success) {
    const Eigen::Matrix3d F = llt.matrixL();
    if (F.allFinite()) {
      p.factored = true;
      const double f[6] = {F(0, 0), F(1, 0), F(2, 0), F(1, 1), F(2, 1), F(2, 2)};
      std::copy(f, f + 6, p.f);
    }
  }
  return p;
}

// theta_of when T is the identity (identity_map): θ = offset + q, θ̇ = q̇ (qd may be null), the
// same values without the terms' loops.
void theta_of_identity(const std::vector<double>& offset, const double* q, const double* qd,
                       double* theta, double* thetad) {
  for (std::size_t a = 0; a < offset.size(); ++a) {
    theta[a] = offset[a] + q[a];
    if (qd) thetad[a] = 0.0 + qd[a];
  }
}

// True if T is the identity: one variable per coordinate, variable i being coordinate i with
// coefficient 1 (an arm whose joints each have a coordinate of their own, in order). Then
// Tᵀ X T = X and Tᵀ x = x: copies.
bool identity_map(const std::vector<std::vector<Term>>& T, Index coordinates) {
  if (static_cast<Index>(T.size()) != coordinates) return false;
  for (std::size_t i = 0; i < T.size(); ++i) {
    if (T[i].size() != 1 || T[i][0].coordinate != static_cast<Index>(i) ||
        T[i][0].coefficient != 1.0)
      return false;
  }
  return true;
}

ForwardPlan forward_plan(const Model& m, const std::vector<int>& ti, bool identity) {
  ForwardPlan plan;
  plan.identity = identity;
  plan.every_pair = true;
  plan.serial = true;
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (m.links[i].parent != static_cast<int>(i) - 1) plan.serial = false;
    LinkPlan p = link_plan(m.links[i]);
    p.ancestors = plan.ancestors.size();
    for (int j = m.links[i].parent; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
      const auto ju = static_cast<std::size_t>(j);
      if (ti[ju] >= 0) plan.ancestors.emplace_back(ju, ti[ju]);
    }
    p.ancestors_end = plan.ancestors.size();
    if (ti[i] >= 0 && static_cast<int>(p.ancestors_end - p.ancestors) != ti[i])
      plan.every_pair = false;
    plan.links.push_back(p);
  }
  return plan;
}

// The joint frame Rj = Rp origin_rotation; with the plan's signed permutation its columns are
// Rp's, signed (the product's value: the other two terms of each entry are exact zeros).
Eigen::Matrix3d joint_frame(const Eigen::Matrix3d& Rp, const Link& L, const LinkPlan& P) {
  if (!P.permutation) return Rp * L.origin_rotation;
  Eigen::Matrix3d Rj;
  for (int c = 0; c < 3; ++c) Rj.col(c) = Rp.col(P.perm[c]) * P.sign[c];
  return Rj;
}

// A link's own inertia for the rigid passes: its CoM c, Ic = R I Rᵀ, and the inertia about the
// world origin written as the start of the composite sums (m, h, I). The own Ī and k are not
// kept apart (link_force_rigid reads c and Ic, the CRBA and G the composite sums); h_own is
// (potential() reads it).
void own_inertia_rigid(const Link& L, const LinkPlan& P, LinkState<double>& w) {
  if (P.massless) {
    w.m_own = 0.0;
    w.h_own.setZero();
    w.Ic.setZero();
    w.c = w.p;
    w.m = 0.0;
    w.h.setZero();
    w.I.setZero();
    return;
  }
  w.c = w.p + w.R * L.com;
  w.m_own = L.mass;
  w.h_own = w.c * L.mass;
  const Eigen::Matrix3d& R = w.R;
  if (P.factored) {
    // I = F Fᵀ (the plan's Cholesky factor), so R I Rᵀ = B Bᵀ with B = R F: 18 products for B
    // (F lower triangular) and 18 for B Bᵀ's upper triangle, against 27 + 18 for R I and (R I) Rᵀ.
    const double* f = P.f;
    Eigen::Matrix3d B;
    B.col(0) = R.col(0) * f[0] + R.col(1) * f[1] + R.col(2) * f[2];
    B.col(1) = R.col(1) * f[3] + R.col(2) * f[4];
    B.col(2) = R.col(2) * f[5];
    w.Ic.col(2).noalias() = B * B.row(2).transpose();  // the upper triangle, then mirrored
    w.Ic.col(1).head<2>().noalias() = B.topRows<2>() * B.row(1).transpose();
    w.Ic(0, 0) = B(0, 0) * B(0, 0) + B(0, 1) * B(0, 1) + B(0, 2) * B(0, 2);
  } else {
    // own_inertia's sums column by column (vectorised; the same products in the same order),
    // the upper triangle mirrored.
    const Eigen::Matrix3d T = R * L.inertia;
    w.Ic.col(2).noalias() = T * R.row(2).transpose();  // the upper triangle, then mirrored
    w.Ic.col(1).head<2>().noalias() = T.topRows<2>() * R.row(1).transpose();
    w.Ic(0, 0) = T(0, 0) * R(0, 0) + T(0, 1) * R(0, 1) + T(0, 2) * R(0, 2);
  }
  w.Ic(1, 0) = w.Ic(0, 1);
  w.Ic(2, 0) = w.Ic(0, 2);
  w.Ic(2, 1) = w.Ic(1, 2);
  const Eigen::Vector3d mc = L.mass * w.c;
  for (int b = 0; b < 3; ++b) w.I.col(b) = w.Ic.col(b) - mc * w.c(b);
  const double mc2 = L.mass * dot3(w.c, w.c);
  for (int a = 0; a < 3; ++a) w.I(a, a) += mc2;
  w.m = L.mass;
  w.h = w.h_own;
}

// place() for a tree without ball joints, with the plan (TreeSubsystem's constructor): the joint
// frame as a signed permutation of the parent's axes, the translation by its nonzero entries,
// a revolute joint about a coordinate axis by place_revolute's column mixing; then
// own_inertia_rigid. Writes what frame_twists and potential() read of the slot (R, p, the axes
// with sl = 0) as place() does.
void place_rigid(const Model& m, const ForwardPlan& plan, const std::vector<int>& ti,
                 const double* theta, LinkState<double>* ws) {
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const Link& L = m.links[i];
    const LinkPlan& P = plan.links[i];
    LinkState<double>& w = ws[i];
    const bool root = L.parent < 0;
    const Eigen::Matrix3d& Rp = root ? m.root_rotation : ws[L.parent].R;
    const Eigen::Vector3d& pp = root ? m.root_translation : ws[L.parent].p;
    const Eigen::Matrix3d Rj = joint_frame(Rp, L, P);
    Eigen::Vector3d t = Eigen::Vector3d::Zero();
    for (int k = 0; k < P.terms; ++k) t += Rp.col(P.term[k]) * L.origin_translation(P.term[k]);
    const Eigen::Vector3d pj = pp + t;
    w.sc = 1.0;
    w.sl[0] = 0.0;
    if (L.type == JointType::revolute) {
      if (P.axis >= 0) {
        turn_about_axis_rigid(P.axis, Rj, theta[ti[i]], w);
      } else {
        place_revolute<double>(L.axis, Rj, theta[ti[i]], w);
      }
      w.p = pj;
      w.sv[0] = pj.cross(w.sw[0]);
    } else if (L.type == JointType::prismatic) {
      w.R = Rj;
      w.sw[0].setZero();
      w.sv[0] = P.axis >= 0 ? Eigen::Vector3d(Rj.col(P.axis)) : Eigen::Vector3d(Rj * L.axis);
      w.p = pj + w.sv[0] * theta[ti[i]];
    } else {
      w.R = Rj;
      w.p = pj;
    }
    own_inertia_rigid(L, P, w);
  }
}

// composite() for the rigid passes: place_rigid started the sums; k is not summed (no scales).
// Down a serial chain (link i's parent i − 1) the child's composite is carried in locals and
// added to link i's own, as ws[p].I += ws[i].I does.
void composite_rigid(const Model& m, const ForwardPlan& plan, LinkState<double>* ws) {
  const std::size_t n = m.links.size();
  if (plan.serial && n > 0) {
    double mass = ws[n - 1].m;
    Eigen::Vector3d h = ws[n - 1].h;
    Eigen::Matrix3d I = ws[n - 1].I;
    for (std::size_t i = n - 1; i-- > 0;) {
      LinkState<double>& w = ws[i];
      mass = w.m + mass;
      h = w.h + h;
      I = w.I + I;
      w.m = mass;
      w.h = h;
      w.I = I;
    }
    return;
  }
  for (std::size_t i = n; i-- > 0;) {
    const int p = m.links[i].parent;
    if (p < 0) continue;
    ws[p].m += ws[i].m;
    ws[p].h += ws[i].h;
    ws[p].I += ws[i].I;
  }
}

// The axes of a serial chain's joint variables as rows (s[k][b]: s_w of variable b for k < 3,
// s_v for k ≥ 3), for chain_pairs; chains of up to kChainPairs variables.
constexpr Index kChainPairs = 32;
struct ChainAxes {
  double s[6][kChainPairs];
};

// The CRBA's pairs of link a of a serial chain whose joint variables are in order
// (ForwardPlan::every_pair: the movable ancestors of variable a are 0 … a − 1): column a above the
// diagonal, M(b, a) = S_bᵀ (n, f) for b < a, down the column from the axes as rows (the sums of
// dot3(s_w, n) + dot3(s_v, f) in the same order, vectorised across b), then mirrored into row a.
void chain_pairs(const ChainAxes& ax, int a, const Eigen::Vector3d& n, const Eigen::Vector3d& f,
                 double* Mt, Index ld) {
  double* col = Mt + a * ld;
  const double n0 = n(0), n1 = n(1), n2 = n(2), f0 = f(0), f1 = f(1), f2 = f(2);
  for (int b = 0; b < a; ++b) {
    col[b] = (ax.s[0][b] * n0 + ax.s[1][b] * n1 + ax.s[2][b] * n2) +
             (ax.s[3][b] * f0 + ax.s[4][b] * f1 + ax.s[5][b] * f2);
  }
  for (int b = 0; b < a; ++b) Mt[a + b * ld] = col[b];
}

// Zeroes Mt (leading dimension ld) unless every pair of joint variables is a link and its
// ancestor (a serial chain: then the CRBA writes every entry).
void zero_unless_every_pair(const ForwardPlan& plan, double* Mt, Index nt, Index ld) {
  if (plan.every_pair) return;
  for (Index j = 0; j < nt; ++j)
    for (Index k = 0; k < nt; ++k) Mt[k + j * ld] = 0.0;
}

// crba_rigid and gravity_forces in one pass over the links, the ancestors from the plan (the
// same sums in the same order; a serial chain's by chain_pairs).
void crba_gravity_rigid(const Model& m, const ForwardPlan& plan, const std::vector<int>& ti,
                        const LinkState<double>* ws, double* Mt, Index nt, Index ld, double* G) {
  zero_unless_every_pair(plan, Mt, nt, ld);
  ChainAxes ax;  // the axes of the variables before a (a serial chain of up to kChainPairs)
  const bool chain = plan.every_pair && nt <= kChainPairs;
  const Eigen::Vector3d& g = m.gravity;
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const int a = ti[i];
    if (a < 0) continue;
    const LinkState<double>& w = ws[i];
    Eigen::Vector3d n, f;
    apply_inertia(w.m, w.h, w.I, w.sw[0], w.sv[0], n, f);
    Mt[a + a * ld] = dot3(w.sw[0], n) + dot3(w.sv[0], f);
    if (chain) {
      chain_pairs(ax, a, n, f, Mt, ld);
      for (int k = 0; k < 3; ++k) {
        ax.s[k][a] = w.sw[0](k);
        ax.s[3 + k][a] = w.sv[0](k);
      }
    } else {
      const LinkPlan& P = plan.links[i];
      for (std::size_t k = P.ancestors; k < P.ancestors_end; ++k) {
        const auto [j, b] = plan.ancestors[k];
        const double v = dot3(ws[j].sw[0], n) + dot3(ws[j].sv[0], f);
        Mt[a + b * ld] = v;
        Mt[b + a * ld] = v;
      }
    }
    const Eigen::Vector3d gn = -w.h.cross(g), gf = -g * w.m;
    G[a] = dot3(w.sw[0], gn) + dot3(w.sv[0], gf);
  }
}

// link_force's rigid case on the CoM: ċ = v_O + ω × c, c̈ = a_O + α × c + ω × ċ, f = m c̈,
// n = c × f + Ic α + ω × Ic ω (Newton–Euler about the CoM, moved to the world origin; its
// scaled form above with λ = 0). Reads c and Ic only, not the own Ī.
void link_force_rigid(bool massless, LinkState<double>& w) {
  w.fe = 0.0;
  if (massless) {
    w.fn.setZero();
    w.ff.setZero();
    return;
  }
  const Eigen::Vector3d cd = w.vv + w.vw.cross(w.c);
  const Eigen::Vector3d cdd = w.av + w.aw.cross(w.c) + w.vw.cross(cd);
  w.ff = cdd * w.m_own;
  Eigen::Matrix<double, 3, 2> av;  // α and ω through Ic in one product
  av << w.aw, w.vw;
  const Eigen::Matrix<double, 3, 2> Iav = w.Ic * av;
  w.fn = w.c.cross(w.ff) + Iav.col(0) + w.vw.cross(Eigen::Vector3d(Iav.col(1)));
}

// velocity_products_rigid's backward pass down a serial chain (link i's parent i − 1): the
// subtree force of link i + 1 carried in locals and added to link i's own, as ws[p].fn += w.fn
// does.
void forces_down_chain(const std::vector<int>& ti, std::size_t n, LinkState<double>* ws,
                       double* tau) {
  Eigen::Vector3d fn = Eigen::Vector3d::Zero(), ff = fn;
  for (std::size_t i = n; i-- > 0;) {
    LinkState<double>& w = ws[i];
    if (i + 1 < n) {
      fn = w.fn + fn;
      ff = w.ff + ff;
      w.fn = fn;
      w.ff = ff;
    } else {
      fn = w.fn;
      ff = w.ff;
    }
    if (ti[i] >= 0) tau[ti[i]] = dot3(w.sw[0], fn) + dot3(w.sv[0], ff);
  }
}

// The velocity products C(θ, θ̇) θ̇ of a tree without ball joints (inverse_dynamics at θ̈ = 0
// without gravity): each link's motion (link_motion, a_0 = 0) and own force in one forward pass,
// then τ and the sums into the parents in one backward pass. Down a serial chain the parent's
// motion and the child's subtree force are carried in locals (the same values and sums).
void velocity_products_rigid(const Model& m, const ForwardPlan& plan, const std::vector<int>& ti,
                             const double* thetad, LinkState<double>* ws, double* tau) {
  Eigen::Vector3d vw = Eigen::Vector3d::Zero(), vv = vw, aw = vw, av = vw;
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    LinkState<double>& w = ws[i];
    const int p = m.links[i].parent;
    if (p >= 0 && !plan.serial) {
      vw = ws[p].vw;
      vv = ws[p].vv;
      aw = ws[p].aw;
      av = ws[p].av;
    } else if (p < 0) {
      vw.setZero();
      vv.setZero();
      aw.setZero();
      av.setZero();
    }
    if (ti[i] >= 0) {  // joint_motion's rigid case at θ̈ = 0, on locals
      const double qd = thetad[ti[i]];
      const Eigen::Vector3d sw = w.sw[0], sv = w.sv[0];
      aw += vw.cross(sw) * qd;
      av += (vw.cross(sv) + vv.cross(sw)) * qd;
      vw += sw * qd;
      vv += sv * qd;
    }
    w.vw = vw;
    w.vv = vv;
    w.aw = aw;
    w.av = av;
    w.vl = 0.0;
    w.al = 0.0;
    link_force_rigid(plan.links[i].massless, w);
  }
  if (plan.serial) {
    forces_down_chain(ti, m.links.size(), ws, tau);
    return;
  }
  for (std::size_t i = m.links.size(); i-- > 0;) {
    const LinkState<double>& w = ws[i];
    if (ti[i] >= 0) tau[ti[i]] = dot3(w.sw[0], w.fn) + dot3(w.sv[0], w.ff);
    const int p = m.links[i].parent;
    if (p >= 0) {
      ws[p].fn += w.fn;
      ws[p].ff += w.ff;
    }
  }
}

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
    } else if (L.type == JointType::floating || L.type == JointType::ball) {
      const std::size_t nc = L.type == JointType::floating ? 7 : 4;
      if (L.terms.size() != nc)
        throw Error(where + ": a " + (nc == 7 ? "floating" : "ball") + " joint has " +
                    std::to_string(nc) + " coordinates, got " + std::to_string(L.terms.size()));
      for (const Term& t : L.terms) {
        if (t.coordinate < 0 || t.coordinate >= nq || t.coefficient != 1.0)
          throw Error(where + ": its variables must be coordinates of the tree");
      }
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

// The workspace in a slot of doubles: the link states, then θ, θ̇, τ_θ, M_θ (nt × nt) and the
// key of the link states (key[0]: the subsystem's tag, key[1]: 1 when the links were placed and
// moved at θ, θ̇ — place, then link_motion at θ̈ = 0 and a_0 = 0 — by that subsystem). Every
// mapping clears key[1]; only a completed pass sets it (mark_moved), so a later call on the slot
// (mass() at another q, say) never leaves stale motions marked as current.
struct Workspace {
  LinkState<double>* links;
  double* theta;
  double* thetad;
  double* Mt;
  double* tau;
  double* key;
};

Index theta_offset(std::size_t links) { return static_cast<Index>(links) * kLinkDoubles; }
Index key_offset(std::size_t links, Index nt) { return theta_offset(links) + 3 * nt + nt * nt; }
Index workspace_doubles(std::size_t links, Index nt) { return key_offset(links, nt) + 2; }

Workspace map_workspace(double* data, std::size_t links, Index nt) {
  Workspace w{};
  w.links = reinterpret_cast<LinkState<double>*>(data);
  for (std::size_t i = 0; i < links; ++i) new (&w.links[i]) LinkState<double>;
  double* rest = data + theta_offset(links);
  w.theta = rest;
  w.thetad = rest + nt;
  w.tau = rest + 2 * nt;
  w.Mt = rest + 3 * nt;
  w.key = data + key_offset(links, nt);
  w.key[1] = 0.0;
  return w;
}

// A subsystem's tag in a key: the bits of its address (models are constant and outlive the
// ForwardData whose slots hold the key).
static_assert(sizeof(std::uintptr_t) == sizeof(double));
double owner_tag(const void* owner) {
  return std::bit_cast<double>(reinterpret_cast<std::uintptr_t>(owner));
}

void mark_moved(const Workspace& w, const void* owner) {
  w.key[0] = owner_tag(owner);
  w.key[1] = 1.0;
}

// The θ, θ̇ (nt each) kept in `placed` (a slot of `size` doubles holding a workspace) if `owner`
// placed and moved its links there (at those joint variables), else null.
const double* moved_by(ConstSlot placed, Index size, std::size_t links, Index nt,
                       const void* owner) {
  if (static_cast<Index>(placed.size()) != size) return nullptr;
  const double* key = placed.data() + key_offset(links, nt);
  const double tag = owner_tag(owner);
  if (key[1] != 1.0 || std::memcmp(key, &tag, sizeof(double)) != 0) return nullptr;
  return placed.data() + theta_offset(links);
}

// The link states of `placed` (a slot of `size` doubles holding a workspace) if `owner` placed
// and moved them at exactly these joint variables (bitwise: the same θ gives the same states),
// else null.
const LinkState<double>* placed_links(ConstSlot placed, Index size, std::size_t links, Index nt,
                                      const void* owner, const double* theta,
                                      const double* thetad) {
  const double* th = moved_by(placed, size, links, nt, owner);
  if (!th) return nullptr;
  const auto bytes = static_cast<std::size_t>(nt) * sizeof(double);
  if (std::memcmp(th, theta, bytes) != 0 || std::memcmp(th + nt, thetad, bytes) != 0)
    return nullptr;
  return reinterpret_cast<const LinkState<double>*>(placed.data());
}

// placed_links for a plan whose joint variables are the coordinates (ForwardPlan::identity):
// θ = offset + q and θ̇ = 0 + q̇ formed entry by entry (theta_of_identity's bits) and compared
// with the slot's as they are formed, without writing them anywhere.
const LinkState<double>* placed_links_identity(ConstSlot placed, Index size, std::size_t links,
                                               Index nt, const void* owner,
                                               const std::vector<double>& offset, const double* q,
                                               const double* qd) {
  const double* th = moved_by(placed, size, links, nt, owner);
  if (!th) return nullptr;
  for (Index a = 0; a < nt; ++a) {
    const double v = offset[static_cast<std::size_t>(a)] + q[a], vd = 0.0 + qd[a];
    if (std::bit_cast<std::uint64_t>(v) != std::bit_cast<std::uint64_t>(th[a]) ||
        std::bit_cast<std::uint64_t>(vd) != std::bit_cast<std::uint64_t>(th[nt + a]))
      return nullptr;
  }
  return reinterpret_cast<const LinkState<double>*>(placed.data());
}

}  // namespace

// ------------------------------------------------------------------------------ derivatives

namespace {

// One tangent direction: value and directional derivative (tree/dual.hpp: no heap, trivially
// copyable into a slot of doubles).
using detail::Dual;
using detail::dual;
using detail::tangent_of;
// Eigen aligns fixed-size vectors of 16 bytes' multiples (LinkState<Dual>) to 16: the workspace
// starts at the first 16-aligned double of its part of the slot (one double of room).
static_assert(sizeof(LinkState<Dual>) % sizeof(double) == 0 && alignof(LinkState<Dual>) <= 16,
              "LinkState<Dual> must live in a slot of doubles");
constexpr Index kDualLinkDoubles = static_cast<Index>(sizeof(LinkState<Dual>) / sizeof(double));
constexpr Index kDualDoubles = static_cast<Index>(sizeof(Dual) / sizeof(double));

Index tangent_workspace_doubles(std::size_t links, Index nt) {
  return static_cast<Index>(links) * kDualLinkDoubles + 4 * nt * kDualDoubles + 1;
}

// Several directions at once (vector-mode forward differentiation, Griewank & Walther 2008,
// §3.1): one lane of the derivative per direction, the values computed once for all of them; a
// fixed number of lanes (no heap), the directions taken kLanes at a time.
constexpr int kLanes = 8;
using Lanes = LaneDual<kLanes>;
constexpr std::size_t kLaneAlign = alignof(LinkState<Lanes>);
static_assert(kLaneAlign % sizeof(double) == 0 && alignof(Lanes) <= kLaneAlign,
              "LinkState<Lanes> must live in a slot of doubles");

// The analytic derivatives' workspace (analytic_workspace below): the links on doubles, θ, θ̇,
// θ̈, τ, the directions per joint variable (22), B^C (49) and Λ, Qm (10) per link and the two
// nt × nt results.
Index analytic_workspace_doubles(std::size_t links, Index nt) {
  return static_cast<Index>(links) * (kLinkDoubles + 59) + 26 * nt + 2 * nt * nt;
}

// The Christoffel matrix's (coriolis()): the links, M_θ and θ on lanes from the first
// kLaneAlign-aligned double, then C_θ, θ, θ̇ and the ball joints' D, W, W_k, D θ̇ on doubles.
Index coriolis_workspace_doubles(std::size_t links, Index nt) {
  const auto n = static_cast<std::size_t>(nt);
  const std::size_t bytes = links * sizeof(LinkState<Lanes>) + (n * n + n) * sizeof(Lanes) +
                            kLaneAlign + (2 * n * n + 9 * n) * sizeof(double);
  return static_cast<Index>((bytes + sizeof(double) - 1) / sizeof(double));
}

// A derivative pass's room: `need` doubles at `offset` of the tree's slot when the slot is the
// tree's (slot_size() doubles), else `own` sized to `need` (a caller without a slot).
double* derivative_room(Slot slot, Index slot_size, Index offset, Index need,
                        std::vector<double>& own) {
  if (static_cast<Index>(slot.size()) >= slot_size) return slot.data() + offset;
  own.resize(static_cast<std::size_t>(need));
  return own.data();
}

// The derivatives' part of a slot (after the forward workspace) starts with a key of its own:
// key[0] the subsystem's tag, key[1] 1 when inverse_dynamics_jacobian()'s analytic pass left its
// links there, placed and moved at the θ, θ̇, θ̈ stored beside them (gravity as a_0 = −g), for
// frame_state_jacobian() to read. The Christoffel matrix's lanes and the analytic passes share
// that room: every mapping of it clears key[1] (derivative_part), only a completed analytic pass
// sets it, so a key never vouches for links another pass has overwritten.
constexpr Index kDerivativeKey = 2;

Index derivative_offset(std::size_t links, Index nt) {
  return workspace_doubles(links, nt) + kDerivativeKey;
}

// derivative_room() at the start of the derivatives' part, its key cleared; `key` (may be null)
// gets the key's address (null without the tree's slot).
double* derivative_part(Slot slot, Index slot_size, std::size_t links, Index nt, Index need,
                        std::vector<double>& own, double** key = nullptr) {
  const bool in_slot = static_cast<Index>(slot.size()) >= slot_size;
  double* k = in_slot ? slot.data() + workspace_doubles(links, nt) : nullptr;
  if (k) k[1] = 0.0;
  if (key) *key = k;
  return derivative_room(slot, slot_size, derivative_offset(links, nt), need, own);
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
// A floating joint as the passes take it: three prismatic joints along the joint frame's x, y, z
// (massless links NAME/x, NAME/y, NAME/z) and a ball joint at their end, as the symbolic chain
// composes it (p = p_joint + R_joint (x, y, z), R = R_joint R(u)).
void split_floating(Link K, std::vector<Link>& out) {
  for (int a = 0; a < 3; ++a) {
    Link P;
    P.name = K.name + "/" + "xyz"[a];
    P.joint = K.joint + "/" + "xyz"[a];
    P.type = JointType::prismatic;
    P.axis = Eigen::Vector3d::Unit(a);
    P.terms = {K.terms[static_cast<std::size_t>(a)]};
    if (a == 0) {
      P.parent = K.parent;
      P.origin_rotation = K.origin_rotation;
      P.origin_translation = K.origin_translation;
    } else {
      P.parent = static_cast<int>(out.size()) - 1;
    }
    out.push_back(std::move(P));
  }
  K.type = JointType::ball;
  K.parent = static_cast<int>(out.size()) - 1;
  K.origin_rotation.setIdentity();
  K.origin_translation.setZero();
  K.terms.erase(K.terms.begin(), K.terms.begin() + 3);
  out.push_back(std::move(K));
}

Model merge_fixed_links(const Model& m, bool merge, std::vector<TreeSubsystem::Placement>& where,
                        double& V0) {
  Model out = m;
  out.links.clear();
  out.points.clear();
  where.assign(m.links.size(), {});
  V0 = 0.0;
  // Per link of out: below a ball or floating joint. A massive link fixed there stays a link of
  // its own: the symbolic chain's kinetic energy gives each body ½ m |ċ|² + ½ ωᵀ J ω, which off
  // |u| = 1 (the scale's rate λ: ċ gains λ (c − o)) is not that of the lumped body (short of
  // λ² Σ m |c_i − c|² / 2), and the two must agree to first order there.
  std::vector<bool> scaled;
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const Link& L = m.links[i];
    TreeSubsystem::Placement parent;  // the root frame
    if (L.parent >= 0) parent = where[static_cast<std::size_t>(L.parent)];
    const Eigen::Matrix3d Rj = parent.R * L.origin_rotation;
    const Eigen::Vector3d pj = parent.p + parent.R * L.origin_translation;
    const bool below = parent.link >= 0 && scaled[static_cast<std::size_t>(parent.link)];
    const bool massive = !(L.mass == 0.0 && L.inertia.isZero(0.0));
    if (L.type != JointType::fixed || !merge || (below && massive)) {
      Link K = L;
      K.parent = parent.link;
      K.origin_rotation = Rj;
      K.origin_translation = pj;
      if (K.type == JointType::floating) {
        split_floating(std::move(K), out.links);
      } else {
        out.links.push_back(std::move(K));
      }
      scaled.resize(out.links.size(),
                    below || L.type == JointType::floating || L.type == JointType::ball);
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
  merged_ = merge_fixed_links(model_, merge_fixed, placement_, potential0_);
  for (Link& L : merged_.links) snap_permutation(L.origin_rotation);
  theta_index_.assign(merged_.links.size(), -1);
  for (std::size_t i = 0; i < merged_.links.size(); ++i) {
    const Link& L = merged_.links[i];
    const int nv = variables(L.type);
    if (nv == 0) continue;
    theta_index_[i] = static_cast<int>(n_theta_);
    quaternions_ = quaternions_ || L.type == JointType::ball;
    for (int k = 0; k < nv; ++k) {  // a ball joint's variable k is its coordinate k
      theta_terms_.push_back(L.type == JointType::ball
                                 ? std::vector<Term>{L.terms[static_cast<std::size_t>(k)]}
                                 : L.terms);
      theta_offset_.push_back(L.type == JointType::ball ? 0.0 : L.offset);
      ++n_theta_;
    }
  }
  plan_ = std::make_shared<const ForwardPlan>(
      forward_plan(merged_, theta_index_, identity_map(theta_terms_, dof())));
  // The forward workspace, then the derivatives': the analytic pass (inverse_dynamics_jacobian(),
  // frame_state_jacobian()) and dual numbers (inverse_dynamics_tangent()), or the Christoffel
  // matrix's lanes (coriolis()).
  slot_size_ = derivative_offset(merged_.links.size(), n_theta_) +
               std::max(analytic_workspace_doubles(merged_.links.size(), n_theta_) +
                            tangent_workspace_doubles(merged_.links.size(), n_theta_),
                        coriolis_workspace_doubles(merged_.links.size(), n_theta_));
}

int TreeSubsystem::link_index(const std::string& name) const {
  if (name == model_.root_name) return -1;
  for (std::size_t i = 0; i < model_.links.size(); ++i) {
    if (model_.links[i].name == name) return static_cast<int>(i);
  }
  return -2;
}

namespace {

// Evaluates with the caller's slot (of `size` doubles: the whole slot) or, without one, a buffer
// of its own as large as the forward workspace that map_workspace() lays out (not the whole slot,
// whose derivative workspaces are several times larger and were zeroed here at every call of a
// caller without slots: potential_energy(system, q) and the residuals per output sample).
template <class F>
void with_workspace(Slot slot, Index size, std::size_t links, Index nt, F&& f) {
  if (static_cast<Index>(slot.size()) >= size) {
    f(map_workspace(slot.data(), links, nt));
  } else {
    std::vector<double> buffer(static_cast<std::size_t>(workspace_doubles(links, nt)));
    f(map_workspace(buffer.data(), links, nt));
  }
}

// θ = offset + T q and θ̇ = T q̇ (qd may be null), T by its rows: the terms of each variable.
void theta_of(const std::vector<std::vector<Term>>& T, const std::vector<double>& offset,
              const double* q, const double* qd, double* theta, double* thetad) {
  for (std::size_t a = 0; a < T.size(); ++a) {
    double th = offset[a], thd = 0.0;
    for (const Term& t : T[a]) {
      th += t.coefficient * q[t.coordinate];
      if (qd) thd += t.coefficient * qd[t.coordinate];
    }
    theta[a] = th;
    if (qd) thetad[a] = thd;
  }
}

// M_q = Tᵀ M_θ T.
void to_coordinates(const std::vector<std::vector<Term>>& T, const double* Mt, MatRef M) {
  const auto nt = static_cast<Index>(T.size());
  if (identity_map(T, M.rows())) {
    M = Eigen::Map<const Mat>(Mt, nt, nt);
    return;
  }
  M.setZero();
  for (Index i = 0; i < nt; ++i) {
    for (Index j = 0; j < nt; ++j) {
      const double v = Mt[i + j * nt];
      if (v == 0.0) continue;
      for (const Term& a : T[static_cast<std::size_t>(i)]) {
        for (const Term& b : T[static_cast<std::size_t>(j)])
          M(a.coordinate, b.coordinate) += a.coefficient * b.coefficient * v;
      }
    }
  }
}

// x_q = Tᵀ x_θ.
void to_coordinates(const std::vector<std::vector<Term>>& T, const double* x, VecRef out) {
  if (identity_map(T, out.size())) {
    out = Eigen::Map<const Vec>(x, out.size());
    return;
  }
  out.setZero();
  for (std::size_t i = 0; i < T.size(); ++i) {
    for (const Term& a : T[i]) out(a.coordinate) += a.coefficient * x[i];
  }
}

}  // namespace

namespace {

// M_θ (leading dimension ld) and G_θ of a tree without ball joints: place_rigid, the composite
// sums, crba_gravity_rigid.
void dynamics_rigid(const Model& m, const ForwardPlan& plan, const std::vector<int>& ti,
                    const Workspace& w, Index nt, double* Mt, Index ld, double* G) {
  place_rigid(m, plan, ti, w.theta, w.links);
  composite_rigid(m, plan, w.links);
  crba_gravity_rigid(m, plan, ti, w.links, Mt, nt, ld, G);
}

// θ (and θ̇: qd may be null) of q, q̇: theta_of_identity when the plan says T is the identity.
void theta_at(const ForwardPlan& plan, const std::vector<std::vector<Term>>& T,
              const std::vector<double>& offset, const double* q, const double* qd, double* theta,
              double* thetad) {
  if (plan.identity) {
    theta_of_identity(offset, q, qd, theta, thetad);
  } else {
    theta_of(T, offset, q, qd, theta, thetad);
  }
}

// The links placed at θ: place_rigid without ball joints (every entry point of the forward
// dynamics places them so, so that dynamics() and mass(), coriolis_times_qd(), gravity(),
// potential() and frame_twists() give the same bits), else place().
void place_for(const Model& m, const ForwardPlan& plan, const std::vector<int>& ti, bool quat,
               const double* theta, LinkState<double>* ws) {
  if (quat) {
    place(m, ti, quat, theta, ws);
  } else {
    place_rigid(m, plan, ti, theta, ws);
  }
}

}  // namespace

void TreeSubsystem::mass(const EvalContext& c, CVecRef q, MatRef M) const {
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_at(*plan_, theta_terms_, theta_offset_, q.data(), nullptr, w.theta, nullptr);
    if (quaternions_) {
      place(merged_, theta_index_, quaternions_, w.theta, w.links);
      composite(merged_, w.links);
      crba(merged_, theta_index_, quaternions_, w.links, w.Mt, n_theta_);
    } else {  // G_θ comes along in τ's room
      dynamics_rigid(merged_, *plan_, theta_index_, w, n_theta_, w.Mt, n_theta_, w.tau);
    }
    to_coordinates(theta_terms_, w.Mt, M);
  });
}

void TreeSubsystem::coriolis_times_qd(const EvalContext& c, CVecRef q, CVecRef qd,
                                      VecRef Cqd) const {
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_at(*plan_, theta_terms_, theta_offset_, q.data(), qd.data(), w.theta, w.thetad);
    if (quaternions_) {
      place(merged_, theta_index_, quaternions_, w.theta, w.links);
      inverse_dynamics<double>(merged_, theta_index_, quaternions_, w.thetad, nullptr, false,
                               w.links, w.tau);
    } else {
      place_rigid(merged_, *plan_, theta_index_, w.theta, w.links);
      velocity_products_rigid(merged_, *plan_, theta_index_, w.thetad, w.links, w.tau);
    }
    to_coordinates(theta_terms_, w.tau, Cqd);
  });
}

void TreeSubsystem::gravity(const EvalContext& c, CVecRef q, VecRef G) const {
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_at(*plan_, theta_terms_, theta_offset_, q.data(), nullptr, w.theta, nullptr);
    if (quaternions_) {
      place(merged_, theta_index_, quaternions_, w.theta, w.links);
      composite(merged_, w.links);
      gravity_forces(merged_, theta_index_, quaternions_, w.links, w.tau);
    } else {  // M_θ comes along in its room
      dynamics_rigid(merged_, *plan_, theta_index_, w, n_theta_, w.Mt, n_theta_, w.tau);
    }
    to_coordinates(theta_terms_, w.tau, G);
  });
}

namespace {

// The links of `placed` (a slot of `size` doubles holding a workspace) if `owner` placed them at
// the joint variables of q, θ = offset + T q (computed as theta_of() does and compared bitwise
// with the θ the slot keeps), else null. The placement alone is asked for: a slot whose links were
// placed and moved (mark_moved) at this θ and any θ̇ qualifies.
const LinkState<double>* placed_at_q(ConstSlot placed, Index size, std::size_t links, Index nt,
                                     const void* owner, const std::vector<std::vector<Term>>& T,
                                     const std::vector<double>& offset, const double* q) {
  const double* th = moved_by(placed, size, links, nt, owner);
  if (!th) return nullptr;
  for (std::size_t a = 0; a < T.size(); ++a) {
    double v = offset[a];
    for (const Term& t : T[a]) v += t.coefficient * q[t.coordinate];
    if (std::memcmp(&v, th + a, sizeof(double)) != 0) return nullptr;
  }
  return reinterpret_cast<const LinkState<double>*>(placed.data());
}

}  // namespace

double TreeSubsystem::potential(const EvalContext& c, CVecRef q) const {
  return potential(q, c.slot, c.slot);
}

double TreeSubsystem::potential(CVecRef q, ConstSlot placed, Slot scratch) const {
  const std::size_t nl = merged_.links.size();
  const auto of_links = [&](const LinkState<double>* links) {
    Eigen::Vector3d h = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < nl; ++i) h += links[i].h_own;
    return -dot3<double>(merged_.gravity, h) + potential0_;  // V = −Σ m g·c
  };
  const LinkState<double>* links =
      placed_at_q(placed, slot_size_, nl, n_theta_, this, theta_terms_, theta_offset_, q.data());
  if (links) return of_links(links);
  double V = 0.0;
  with_workspace(scratch, slot_size_, nl, n_theta_, [&](Workspace w) {
    theta_at(*plan_, theta_terms_, theta_offset_, q.data(), nullptr, w.theta, nullptr);
    place_for(merged_, *plan_, theta_index_, quaternions_, w.theta, w.links);
    V = of_links(w.links);
  });
  return V;
}

double TreeSubsystem::dynamics(const EvalContext& c, CVecRef q, CVecRef qd, MatRef M, VecRef Cqd,
                               VecRef G) const {
  with_workspace(c.slot, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    // θ = q (each joint its own coordinate, in order): the passes write M, G, C q̇ themselves.
    const bool direct = plan_->identity;
    theta_at(*plan_, theta_terms_, theta_offset_, q.data(), qd.data(), w.theta, w.thetad);
    if (!quaternions_) {
      dynamics_rigid(merged_, *plan_, theta_index_, w, n_theta_, direct ? M.data() : w.Mt,
                     direct ? M.outerStride() : n_theta_, direct ? G.data() : w.tau);
      if (!direct) {
        to_coordinates(theta_terms_, w.Mt, M);
        to_coordinates(theta_terms_, w.tau, G);
      }
      velocity_products_rigid(merged_, *plan_, theta_index_, w.thetad, w.links,
                              direct ? Cqd.data() : w.tau);
      mark_moved(w, this);  // the motions frame_twists reuses
      if (!direct) to_coordinates(theta_terms_, w.tau, Cqd);
      return;
    }
    place(merged_, theta_index_, quaternions_, w.theta, w.links);
    composite(merged_, w.links);
    if (direct) {
      crba(merged_, theta_index_, quaternions_, w.links, M.data(), n_theta_, M.outerStride());
    } else {
      crba(merged_, theta_index_, quaternions_, w.links, w.Mt, n_theta_);
      to_coordinates(theta_terms_, w.Mt, M);
    }
    gravity_forces(merged_, theta_index_, quaternions_, w.links, direct ? G.data() : w.tau);
    if (!direct) to_coordinates(theta_terms_, w.tau, G);
    inverse_dynamics<double>(merged_, theta_index_, quaternions_, w.thetad, nullptr, false, w.links,
                             direct ? Cqd.data() : w.tau);
    mark_moved(w, this);  // the velocity products' pass: the motions frame_twists reuses
    if (!direct) to_coordinates(theta_terms_, w.tau, Cqd);
  });
  return 0.0;
}

namespace {

// The Christoffel matrix's workspace, from the start of the derivatives' part of the slot (after
// the forward workspace; coriolis() and the derivatives are never in use at the same time, so
// they share it) or in a buffer of its own: from the first kLaneAlign-aligned double, the links,
// M_θ (nt × nt) and θ on lanes; then, on doubles, C_θ (nt × nt), θ, θ̇ and, for the ball joints'
// term (radial_christoffel), D (nt × nt), its W and W_k (3 × nt each) and D θ̇.
struct CoriolisWorkspace {
  LinkState<Lanes>* links;
  Lanes* Mt;
  Lanes* theta;
  double* Ct;
  double* th;
  double* thd;
  double* D;
  double* W;
  double* Wk;
  double* Dq;
};

CoriolisWorkspace coriolis_workspace(Slot slot, Index slot_size, std::size_t nl, Index nt,
                                     std::vector<double>& own) {
  double* base = derivative_part(slot, slot_size, nl, nt, coriolis_workspace_doubles(nl, nt), own);
  while (reinterpret_cast<std::uintptr_t>(base) % kLaneAlign != 0) ++base;
  CoriolisWorkspace w{};
  w.links = reinterpret_cast<LinkState<Lanes>*>(base);
  for (std::size_t i = 0; i < nl; ++i) new (&w.links[i]) LinkState<Lanes>;
  w.Mt = reinterpret_cast<Lanes*>(w.links + nl);
  for (Index k = 0; k < nt * nt + nt; ++k) new (&w.Mt[k]) Lanes;
  w.theta = w.Mt + nt * nt;
  w.Ct = reinterpret_cast<double*>(w.theta + nt);
  w.th = w.Ct + nt * nt;
  w.thd = w.th + nt;
  w.D = w.thd + nt;
  w.W = w.D + nt * nt;
  w.Wk = w.W + 3 * nt;
  w.Dq = w.Wk + 3 * nt;
  return w;
}

// The values of a vector or matrix on lanes.
template <int R, int C>
Eigen::Matrix<double, R, C> lane_values(const Eigen::Matrix<Lanes, R, C>& x) {
  return x.unaryExpr([](const Lanes& e) { return e.value(); });
}

// The symbolic chain's M(q) and the tree's agree on |u| = 1 but not in their derivatives along a
// ball joint k's radial direction (ρ_k = ln |u_k|): the symbolic body rates grow there as
// ∂Ω_b/∂ρ_k = 2 Ω_b^(≤k) (the columns of the joints at or above k; rate_scale_terms), the tree's
// as the rotation's while its I_b = R J Rᵀ grows as |u_k|⁴. So ∂M_sym/∂ρ_k = ∂M_tree/∂ρ_k + D_k,
// D_k = Σ_{b below k} 2 (Ω^(≤k)ᵀ I_b Ω + Ωᵀ I_b Ω^(≤k)) − 4 Ωᵀ I_b Ω (Ω: the bodies' angular
// columns S_w, 3 × nt), and the Christoffel matrix of M_sym adds, with ∂ρ_k/∂θ_c = u_c / |u|²,
// ½ (ρ̇_k D_k + (D_k θ̇) ∂ρ_kᵀ − ∂ρ_k (D_k θ̇)ᵀ) to the tree's (column-major Ct, nt × nt). The
// links' values (Ic, S_w) from the lanes' placement at θ; D, W, W_k, D θ̇ in the workspace.
void radial_christoffel(const Model& m, const std::vector<int>& ti, const CoriolisWorkspace& w,
                        Index nt) {
  const std::size_t nl = m.links.size();
  const Eigen::Map<const Vec> thd(w.thd, nt);
  Eigen::Map<Mat> D(w.D, nt, nt), W(w.W, 3, nt), Wk(w.Wk, 3, nt);
  Eigen::Map<Vec> Dq(w.Dq, nt);
  for (std::size_t k = 0; k < nl; ++k) {
    if (m.links[k].type != JointType::ball) continue;
    const auto a = static_cast<Index>(ti[k]);
    const Eigen::Map<const Eigen::Vector4d> u(w.th + a);
    const Eigen::Vector4d drho = u / u.squaredNorm();
    D.setZero();
    for (std::size_t b = k; b < nl; ++b) {
      bool below = false;  // b in the subtree of k
      for (int j = static_cast<int>(b); j >= 0 && !below;
           j = m.links[static_cast<std::size_t>(j)].parent)
        below = static_cast<std::size_t>(j) == k;
      const Eigen::Matrix3d Ic = lane_values(w.links[b].Ic);
      if (!below || Ic.isZero(0.0)) continue;
      W.setZero();
      Wk.setZero();
      bool at_or_above_k = false;
      for (int j = static_cast<int>(b); j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
        const auto ju = static_cast<std::size_t>(j);
        at_or_above_k = at_or_above_k || ju == k;
        if (ti[ju] < 0) continue;
        for (int c = 0; c < variables(m.links[ju].type); ++c) {
          W.col(ti[ju] + c) = lane_values(w.links[ju].sw[c]);
          if (at_or_above_k) Wk.col(ti[ju] + c) = W.col(ti[ju] + c);
        }
      }
      for (Index j = 0; j < nt; ++j) {  // fixed-size products: no temporaries on the heap
        const Eigen::Vector3d IW = Ic * W.col(j), IWk = Ic * Wk.col(j);
        for (Index i = 0; i < nt; ++i) {
          const Eigen::Vector3d wi = W.col(i), wki = Wk.col(i);
          D(i, j) += 2.0 * (wki.dot(IW) + wi.dot(IWk)) - 4.0 * wi.dot(IW);
        }
      }
    }
    const double rhod = drho.dot(thd.segment(a, 4));
    for (Index i = 0; i < nt; ++i) Dq(i) = D.row(i).dot(thd);
    for (Index i = 0; i < nt; ++i) {
      for (Index j = 0; j < nt; ++j) {
        double c = rhod * D(i, j);
        if (j >= a && j < a + 4) c += drho(j - a) * Dq(i);
        if (i >= a && i < a + 4) c -= drho(i - a) * Dq(j);
        w.Ct[i + j * nt] += 0.5 * c;
      }
    }
  }
}

}  // namespace

// The Christoffel matrix of the first kind, C_ij = Σ_k ½ (∂M_ij/∂θ_k + ∂M_ik/∂θ_j − ∂M_jk/∂θ_i) θ̇_k
// (Spong, Hutchinson & Vidyasagar, Robot Modeling and Control, 2006, §7.3: Ṁ − 2C skew-symmetric),
// in the joint variables, then C_q = Tᵀ C_θ T. ∂M/∂θ_k by the CRBA on lanes, kLanes directions
// e_k of θ per pass (vector-mode forward differentiation, Griewank & Walther 2008, §3.1); each
// direction k adds its three terms: ½ θ̇_k ∂M/∂θ_k to all of C, ½ (∂M/∂θ_k) θ̇ to column k and
// −½ ((∂M/∂θ_k) θ̇)ᵀ to row k. In the slot's derivatives part: allocation-free with a slot.
[[gnu::flatten]] void TreeSubsystem::coriolis(const EvalContext& c, CVecRef q, CVecRef qd,
                                              MatRef C) const {
  const Index nt = n_theta_;
  std::vector<double> own;
  const CoriolisWorkspace w = coriolis_workspace(c.slot, slot_size_, merged_.links.size(), nt, own);
  theta_of(theta_terms_, theta_offset_, q.data(), qd.data(), w.th, w.thd);
  for (Index k = 0; k < nt * nt; ++k) w.Ct[k] = 0.0;
  for (Index k0 = 0; k0 < nt; k0 += kLanes) {
    for (Index k = 0; k < nt; ++k) {
      w.theta[k] = Lanes(w.th[k]);
      if (k >= k0 && k < k0 + kLanes) w.theta[k].d[k - k0] = 1.0;
    }
    place(merged_, theta_index_, quaternions_, w.theta, w.links);
    composite(merged_, w.links);
    crba(merged_, theta_index_, quaternions_, w.links, w.Mt, nt);
    for (Index k = k0; k < std::min<Index>(nt, k0 + kLanes); ++k) {
      const Index l = k - k0;
      const double half_rate = 0.5 * w.thd[k];
      for (Index j = 0; j < nt; ++j) {
        double dm_qd = 0.0;  // ((∂M/∂θ_k) θ̇)_j
        for (Index i = 0; i < nt; ++i) {
          const double dm = w.Mt[i + j * nt].d[l];
          w.Ct[i + j * nt] += half_rate * dm;
          dm_qd += dm * w.thd[i];
        }
        w.Ct[j + k * nt] += 0.5 * dm_qd;  // column k
        w.Ct[k + j * nt] -= 0.5 * dm_qd;  // row k
      }
    }
  }
  if (quaternions_) radial_christoffel(merged_, theta_index_, w, nt);
  to_coordinates(theta_terms_, w.Ct, C);  // C_q = Tᵀ C_θ T
}

void TreeSubsystem::link_pose(CVecRef q, int link, Eigen::Matrix3d& R, Eigen::Vector3d& p) const {
  R = model_.root_rotation;
  p = model_.root_translation;
  if (link < 0) return;
  const Placement& at = placement_[static_cast<std::size_t>(link)];
  if (at.link >= 0) {
    std::vector<double> theta(static_cast<std::size_t>(n_theta_));
    theta_of(theta_terms_, theta_offset_, q.data(), nullptr, theta.data(), nullptr);
    std::vector<LinkState<double>> ws(merged_.links.size());
    place(merged_, theta_index_, quaternions_, theta.data(), ws.data());
    R = ws[static_cast<std::size_t>(at.link)].R;
    p = ws[static_cast<std::size_t>(at.link)].p;
  }
  p += R * at.p;
  R = R * at.R;
}

void TreeSubsystem::link_poses(CVecRef q, std::vector<Eigen::Matrix3d>& R,
                               std::vector<Eigen::Vector3d>& p) const {
  std::vector<double> theta(static_cast<std::size_t>(n_theta_));
  theta_of(theta_terms_, theta_offset_, q.data(), nullptr, theta.data(), nullptr);
  std::vector<LinkState<double>> ws(merged_.links.size());
  place(merged_, theta_index_, quaternions_, theta.data(), ws.data());
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

// A point p fixed in link i moves with the link's motion (ω, λ, v_O) about the world origin:
// ṗ = v_O + ω × p + λ p, Ṙ = ([ω]× + λ) R, p̈ = a_O + α × p + λ̇ p + ω × ṗ + λ ṗ,
// R̈ = ([α]× + λ̇ + ([ω]× + λ)²) R, with (α, λ̇, a_O) the link's acceleration (link_motion; λ = 0
// without ball joints). Each joint variable k above the link moves it by ∂p/∂θ_k = s_v + s_w × p
// + s_l p, ∂R/∂θ_k = ([s_w]× + s_l) R (S_k = (s_w, s_l, s_v)); through θ = T q + c,
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
  S vl(0.0), al(0.0);
  if (link >= 0) {
    const LinkState<S>& L = ws[link];
    Rl = L.R;
    pl = L.p;
    vw = L.vw;
    vv = L.vv;
    aw = L.aw;
    av = L.av;
    vl = L.vl;
    al = L.al;
  }
  FrameMotion<S> f;
  f.p = pl + Rl * x_offset.cast<S>();
  f.R = Rl * R_offset.cast<S>();
  f.pd = vv + vw.cross(f.p) + f.p * vl;
  f.pdd = av + aw.cross(f.p) + f.p * al + vw.cross(f.pd) + f.pd * vl;
  const M3<S> W = skew<S>(vw) + M3<S>::Identity() * vl;
  f.Rd = W * f.R;
  f.Rdd = (skew<S>(aw) + M3<S>::Identity() * al + W * W) * f.R;
  return f;
}

// True if R is exactly the identity (then R X = X and R x = x: 1 × x plus exact zeros).
bool is_identity(const Eigen::Matrix3d& R) { return R == Eigen::Matrix3d::Identity(); }

// frame_motion of a tree without ball joints (λ = 0, α and ω of the link's motion), written into
// `out`: Ṙ and R̈ column by column, Ṙ_c = ω × R_c (the entries of [ω]× R without its exact zero
// terms: the same bits) and R̈_c = α × R_c + ω × Ṙ_c (([α]× + [ω]×²) R regrouped: 6 cross
// products instead of three 3 × 3 products; equal to round-off).
void frame_motion_rigid(const Model& m, const LinkState<double>* ws, int link,
                        const Eigen::Matrix3d& R_offset, const Eigen::Vector3d& x_offset,
                        FrameState& out) {
  if (link < 0) {
    out.p = m.root_translation + m.root_rotation * x_offset;
    out.R = m.root_rotation * R_offset;
    out.pd.setZero();
    out.pdd.setZero();
    out.Rd.setZero();
    out.Rdd.setZero();
    return;
  }
  const LinkState<double>& L = ws[link];
  const Eigen::Vector3d vw = L.vw, aw = L.aw;
  out.p = L.p + L.R * x_offset;
  if (is_identity(R_offset)) {
    out.R = L.R;
  } else {
    out.R.noalias() = L.R * R_offset;
  }
  out.pd = L.vv + vw.cross(out.p);
  out.pdd = L.av + aw.cross(out.p) + vw.cross(out.pd);
  for (int c = 0; c < 3; ++c) {
    const Eigen::Vector3d Rc = out.R.col(c);
    const Eigen::Vector3d Rdc = vw.cross(Rc);
    out.Rd.col(c) = Rdc;
    out.Rdd.col(c) = aw.cross(Rc) + vw.cross(Rdc);
  }
}

// The terms of joint variable k of link L: a ball joint's variable k is its coordinate k.
std::pair<const Term*, const Term*> variable_terms(const Link& L, int k) {
  if (L.type == JointType::ball)
    return {&L.terms[static_cast<std::size_t>(k)], &L.terms[static_cast<std::size_t>(k)] + 1};
  return {L.terms.data(), L.terms.data() + L.terms.size()};
}

// The columns ∂p/∂q_j, ∂R/∂q_j (R row-major) of the frame at (p, R) on link `link`: col(j, dp,
// dR) is called once per joint term above the link, with the coefficient applied.
template <class S, class F>
void frame_columns(const Model& m, const std::vector<int>& ti, const LinkState<S>* ws, int link,
                   const V3<S>& p, const M3<S>& R, F&& col) {
  for (int j = link; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
    const auto ju = static_cast<std::size_t>(j);
    if (ti[ju] < 0) continue;
    const Link& L = m.links[ju];
    for (int k = 0; k < variables(L.type); ++k) {
      const LinkState<S>& w = ws[ju];
      V3<S> dp = w.sv[k] + w.sw[k].cross(p);
      M3<S> dR = skew<S>(w.sw[k]) * R;
      if (L.type == JointType::ball) {
        dp += p * w.sl[k];
        dR += R * w.sl[k];
      }
      const auto [first, last] = variable_terms(L, k);
      for (const Term* t = first; t != last; ++t) col(t->coordinate, t->coefficient, dp, dR);
    }
  }
}

// A frame (R_offset, x_offset) of link `frame_link` of the model as given, on the merged tree: its
// link there, the offset composed with the link's placement.
struct MergedFrame {
  int link = -1;
  Eigen::Matrix3d R;
  Eigen::Vector3d x;
};

MergedFrame merged_frame(const std::vector<TreeSubsystem::Placement>& placement, int frame_link,
                         const Eigen::Matrix3d& R_offset, const Eigen::Vector3d& x_offset) {
  if (frame_link < 0) return {-1, R_offset, x_offset};
  const TreeSubsystem::Placement& at = placement[static_cast<std::size_t>(frame_link)];
  if (is_identity(at.R)) return {at.link, R_offset, at.p + x_offset};
  return {at.link, at.R * R_offset, at.p + at.R * x_offset};
}

void copy_motion(const FrameMotion<double>& f, FrameState& out) {
  out.p = f.p;
  out.R = f.R;
  out.pd = f.pd;
  out.pdd = f.pdd;
  out.Rd = f.Rd;
  out.Rdd = f.Rdd;
}

// The frame's motion f and its columns ∂p/∂q, ∂R/∂q (R row-major) into `out`.
void copy_state(const Model& m, const std::vector<int>& ti, const LinkState<double>* ws, int link,
                const FrameMotion<double>& f, FrameState& out) {
  copy_motion(f, out);
  out.dp.setZero();
  out.dR.setZero();
  frame_columns(m, ti, ws, link, f.p, f.R,
                [&](Index c, double k, const Eigen::Vector3d& dp, const Eigen::Matrix3d& dR) {
                  out.dp.col(c) += k * dp;
                  for (int r = 0; r < 9; ++r) out.dR(r, c) += k * dR(r / 3, r % 3);
                });
}

// The frame's columns as twists (v, ω, s) per coordinate (7 × cols, column-major, zeroed first):
// joint variable k above the link moves the frame at p by v = s_v + s_w × p + s_l p, ω = s_w,
// s = s_l (frame_columns' ∂p/∂θ_k and ∂R/∂θ_k = ([s_w]× + s_l) R), through θ = T q + c.
void twist_columns(const Model& m, const std::vector<int>& ti, const LinkState<double>* ws,
                   int link, const Eigen::Vector3d& p, Index cols, double* twists) {
  std::fill_n(twists, 7 * cols, 0.0);
  for (int j = link; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
    const auto ju = static_cast<std::size_t>(j);
    if (ti[ju] < 0) continue;
    const Link& L = m.links[ju];
    const LinkState<double>& w = ws[ju];
    for (int k = 0; k < variables(L.type); ++k) {
      const Eigen::Vector3d v = w.sv[k] + w.sw[k].cross(p) + p * w.sl[k];
      const auto [first, last] = variable_terms(L, k);
      for (const Term* t = first; t != last; ++t) {
        double* c = twists + 7 * t->coordinate;
        for (int r = 0; r < 3; ++r) {
          c[r] += t->coefficient * v(r);
          c[3 + r] += t->coefficient * w.sw[k](r);
        }
        c[6] += t->coefficient * w.sl[k];
      }
    }
  }
}

// twist_columns of a tree without ball joints whose joint variables are its coordinates
// (ForwardPlan::identity): each movable link at or above `link` writes its own column
// (s_v + s_w × p, s_w, 0) (the bits of twist_columns' 0 + 1 × x); the others are zeroed unless
// every column is written.
void twist_columns_rigid(const ForwardPlan& plan, const std::vector<int>& ti,
                         const LinkState<double>* ws, int link, const Eigen::Vector3d& p,
                         Index cols, double* twists) {
  const auto put = [&](const LinkState<double>& w, int a) {
    double* c = twists + 7 * a;
    const Eigen::Vector3d sw = w.sw[0], v = w.sv[0] + sw.cross(p);
    for (int r = 0; r < 3; ++r) {
      c[r] = v(r);
      c[3 + r] = sw(r);
    }
    c[6] = 0.0;
  };
  if (link < 0) {
    std::fill_n(twists, 7 * cols, 0.0);
    return;
  }
  const auto lu = static_cast<std::size_t>(link);
  const LinkPlan& P = plan.links[lu];
  const auto written = static_cast<Index>(P.ancestors_end - P.ancestors) + (ti[lu] >= 0 ? 1 : 0);
  if (written != cols) std::fill_n(twists, 7 * cols, 0.0);
  if (ti[lu] >= 0) put(ws[lu], ti[lu]);
  for (std::size_t k = P.ancestors; k < P.ancestors_end; ++k)
    put(ws[plan.ancestors[k].first], plan.ancestors[k].second);
}

}  // namespace

void TreeSubsystem::frame_twists(CVecRef q, CVecRef qd, int frame_link,
                                 const Eigen::Matrix3d& R_offset, const Eigen::Vector3d& x_offset,
                                 ConstSlot placed, Slot scratch, FrameState& out,
                                 double* twists) const {
  const MergedFrame at = merged_frame(placement_, frame_link, R_offset, x_offset);
  const std::size_t nl = merged_.links.size();
  const LinkState<double>* links =
      plan_->identity ? placed_links_identity(placed, slot_size_, nl, n_theta_, this, theta_offset_,
                                              q.data(), qd.data())
                      : nullptr;
  with_workspace(scratch, slot_size_, nl, n_theta_, [&](Workspace w) {
    if (!links) {
      theta_at(*plan_, theta_terms_, theta_offset_, q.data(), qd.data(), w.theta, w.thetad);
      links = placed_links(placed, slot_size_, nl, n_theta_, this, w.theta, w.thetad);
    }
    if (!links) {  // not placed at this state: the pass of frame_state
      place_for(merged_, *plan_, theta_index_, quaternions_, w.theta, w.links);
      link_motion<double>(merged_, theta_index_, quaternions_, w.thetad, nullptr,
                          Eigen::Vector3d::Zero(), w.links);
      mark_moved(w, this);
      links = w.links;
    }
    if (!quaternions_ && plan_->identity) {
      frame_motion_rigid(merged_, links, at.link, at.R, at.x, out);
      twist_columns_rigid(*plan_, theta_index_, links, at.link, out.p, dof(), twists);
      return;
    }
    const FrameMotion<double> f = frame_motion(merged_, links, at.link, at.R, at.x);
    copy_motion(f, out);
    twist_columns(merged_, theta_index_, links, at.link, f.p, dof(), twists);
  });
}

void TreeSubsystem::frame_state(CVecRef q, CVecRef qd, int frame_link,
                                const Eigen::Matrix3d& frame_R_offset,
                                const Eigen::Vector3d& frame_x_offset, Slot scratch,
                                FrameState& out) const {
  const MergedFrame at = merged_frame(placement_, frame_link, frame_R_offset, frame_x_offset);
  const int link = at.link;
  with_workspace(scratch, slot_size_, merged_.links.size(), n_theta_, [&](Workspace w) {
    theta_at(*plan_, theta_terms_, theta_offset_, q.data(), qd.data(), w.theta, w.thetad);
    place_for(merged_, *plan_, theta_index_, quaternions_, w.theta, w.links);
    link_motion<double>(merged_, theta_index_, quaternions_, w.thetad, nullptr,
                        Eigen::Vector3d::Zero(), w.links);
    mark_moved(w, this);
    const FrameMotion<double> f = frame_motion(merged_, w.links, link, at.R, at.x);
    copy_state(merged_, theta_index_, w.links, link, f, out);
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
  double* base = derivative_room(slot, slot_size, slot_size - need, need, own);
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

// θ, θ̇ seeded with dθ = T dq, dθ̇ = T dq̇; θ̈ = T q̈ held (no tangent).
void seed_duals(const std::vector<std::vector<Term>>& T, const std::vector<double>& offset,
                CVecRef q, CVecRef qd, CVecRef qdd, CVecRef dq, CVecRef dqd,
                const DualWorkspace& w) {
  for (std::size_t k = 0; k < T.size(); ++k) {
    double v = offset[k], dv = 0.0, s = 0.0, ds = 0.0, a = 0.0;
    for (const Term& t : T[k]) {
      v += t.coefficient * q(t.coordinate);
      dv += t.coefficient * dq(t.coordinate);
      s += t.coefficient * qd(t.coordinate);
      ds += t.coefficient * dqd(t.coordinate);
      a += t.coefficient * qdd(t.coordinate);
    }
    w.theta[k] = dual(v, dv);
    w.thetad[k] = dual(s, ds);
    w.thetadd[k] = dual(a, 0.0);
  }
}

double value_of(const Dual& x) { return x.value(); }

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
  seed_duals(theta_terms_, theta_offset_, q, qd, qdd, dq, dqd, w);
  place(merged_, theta_index_, quaternions_, w.theta, w.links);
  link_motion<Dual>(merged_, theta_index_, quaternions_, w.thetad, w.thetadd, V3<Dual>::Zero(),
                    w.links);
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
  seed_duals(theta_terms_, theta_offset_, q, qd, qdd, dq, dqd, w);
  place(merged_, theta_index_, quaternions_, w.theta, w.links);
  inverse_dynamics<Dual>(merged_, theta_index_, quaternions_, w.thetad, w.thetadd, true, w.links,
                         w.tau);
  dID.setZero();
  for (std::size_t k = 0; k < theta_terms_.size(); ++k) {
    const double d = tangent_of(w.tau[k]);
    for (const Term& t : theta_terms_[k]) dID(t.coordinate) += t.coefficient * d;
  }
  return true;
}

namespace {

// A frame of model() on the merged tree: its link there, the offset composed with the link's
// placement.
void on_merged(const std::vector<TreeSubsystem::Placement>& placement, int frame_link, int& link,
               Eigen::Matrix3d& R_offset, Eigen::Vector3d& x_offset) {
  link = -1;
  if (frame_link < 0) return;
  const TreeSubsystem::Placement& at = placement[static_cast<std::size_t>(frame_link)];
  link = at.link;
  x_offset = at.p + at.R * x_offset;
  R_offset = at.R * R_offset;
}

}  // namespace

namespace {

// ------------------------------------------------------- analytic derivatives of the RNEA
//
// J. Carpentier, N. Mansard, "Analytical Derivatives of Rigid Body Dynamics Algorithms", RSS 2018
// (and the closed forms of S. Singh, R. P. Russell, P. M. Wensing, "Efficient Analytical
// Derivatives of Rigid-Body Dynamics using Spatial Vector Algebra", IEEE RA-L 7(2), 2022), in the
// world coordinates the passes use, for trees of revolute and prismatic joints (one variable per
// joint, no scales). A change δθ_j moves the subtree of joint j rigidly by the screw S_j: every
// world motion x below it changes by S_j × x, every force by S_j ×* x, every inertia by
// S_j ×* I − I S_j ×, and the RNEA's quantities also change by what is not carried along,
//   δv_i = S_j × v_i + Ψ̇_j,   δa_i = S_j × a_i + Ψ̈_j + Ψ̇_j × v_i   (i in the subtree of j),
//   Ψ̇_j = v_λ(j) × S_j,   Ψ̈_j = a_λ(j) × S_j + v_λ(j) × Ψ̇_j   (λ(j): j's parent, a_0 = −g),
// and a change δθ̇_j by δv_i = S_j, δa_i = 2 Ψ̇_j + S_j × v_i. The link's force f = I a + v ×* I v
// then changes by S_j ×* f (carried, which leaves τ_k = S_kᵀ F_k unchanged when S_k moves with
// it) plus I δa + B δv, B u = v ×* I u − I (v × u) + u ×* I v (the paper's B_i); summed over the
// subtrees (composite I^C and B^C, F the subtree's force):
//   ∂τ_k/∂θ_j = S_kᵀ (S_j ×* F_j + I^C_j Ψ̈_j + B^C_j Ψ̇_j)   for k an ancestor of j or j itself,
//             = (I^C_k S_k)ᵀ Ψ̈_j + (B^C_kᵀ S_k)ᵀ Ψ̇_j          for k below j,
//   ∂τ_k/∂θ̇_j = S_kᵀ (I^C_j 2Ψ̇_j + B^C_j S_j)               for k an ancestor of j or j itself,
//             = (I^C_k S_k)ᵀ 2Ψ̇_j + (B^C_kᵀ S_k)ᵀ S_j        for k below j.
// One forward pass (placement, v, a, Ψ̇, Ψ̈) and one backward pass (I^C, B^C, F), then O(n d)
// products of 6-vectors for the n × n entries (d: the depth of the tree).

using V6 = Eigen::Matrix<double, 6, 1>;

// A motion (ω, v_O) or a force (n_O, f) about the world origin as one 6-vector.
V6 six(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  V6 x;
  x << a, b;
  return x;
}

// (ω1, v1) × (ω2, v2) = (ω1 × ω2, ω1 × v2 + v1 × ω2).
V6 cross_motion(const V6& a, const V6& b) {
  const Eigen::Vector3d aw = a.head<3>(), av = a.tail<3>(), bw = b.head<3>(), bv = b.tail<3>();
  return six(aw.cross(bw), aw.cross(bv) + av.cross(bw));
}

// (ω, v) ×* (n, f) = (ω × n + v × f, ω × f).
V6 cross_force(const V6& a, const V6& f) {
  const Eigen::Vector3d aw = a.head<3>(), av = a.tail<3>(), n = f.head<3>(), ff = f.tail<3>();
  return six(aw.cross(n) + av.cross(ff), aw.cross(ff));
}

// I u for the spatial inertia (m, h, Ī) about the world origin (apply_inertia).
V6 inertia_times(double m, const Eigen::Vector3d& h, const Eigen::Matrix3d& I, const V6& u) {
  Eigen::Vector3d n, f;
  apply_inertia<double>(m, h, I, u.head<3>(), u.tail<3>(), n, f);
  return six(n, f);
}

V6 composite_times(const LinkState<double>& w, const V6& u) {
  return inertia_times(w.m, w.h, w.I, u);
}

// The analytic pass's workspace after the forward workspace of a slot (or in `own`): the links,
// θ, θ̇, θ̈, τ (nt each), the directions (Ψ̇ and Ψ̈, 6 + 6 per joint variable; with ball joints
// P, Q, Q̇ and δλ, 22), B^C (its blocks B₁₁, B₂₁: 18 per link, column-major, see
// analytic_passes; with ball joints the whole 7 × 7, 49), Λ and Qm (10 per link, with ball
// joints), then ∂τ/∂θ and ∂τ/∂θ̇ (nt × nt each, column-major).
struct AnalyticWorkspace {
  double* key;  // the derivatives' key (null in a buffer of its own)
  LinkState<double>* links;
  double* theta;
  double* thetad;
  double* thetadd;
  double* tau;
  double* psi;
  double* B;
  double* ext;
  double* Dq;
  double* Dqd;
};

AnalyticWorkspace analytic_workspace(Slot slot, Index slot_size, std::size_t nl, Index nt,
                                     std::vector<double>& own) {
  double* key = nullptr;
  double* base =
      derivative_part(slot, slot_size, nl, nt, analytic_workspace_doubles(nl, nt), own, &key);
  AnalyticWorkspace w{};
  w.key = key;
  w.links = reinterpret_cast<LinkState<double>*>(base);
  for (std::size_t i = 0; i < nl; ++i) new (&w.links[i]) LinkState<double>;
  w.theta = base + static_cast<Index>(nl) * kLinkDoubles;
  w.thetad = w.theta + nt;
  w.thetadd = w.thetad + nt;
  w.tau = w.thetadd + nt;
  w.psi = w.tau + nt;
  w.B = w.psi + 22 * nt;
  w.ext = w.B + 49 * static_cast<Index>(nl);
  w.Dq = w.ext + 10 * static_cast<Index>(nl);
  w.Dqd = w.Dq + nt * nt;
  return w;
}

V6 axis_of(const LinkState<double>& w) { return six(w.sw[0], w.sv[0]); }

// The forward pass: placement, v, a (gravity as a_0 = −g) and the subtree forces F (the RNEA on
// doubles), the composite inertias, Ψ̇_j, Ψ̈_j per joint and B^C per link (own B, then the
// backward sum).
void analytic_passes(const Model& m, const std::vector<int>& ti, const AnalyticWorkspace& w) {
  LinkState<double>* ws = w.links;
  place<double>(m, ti, false, w.theta, ws);
  composite<double>(m, ws);
  inverse_dynamics<double>(m, ti, false, w.thetad, w.thetadd, true, ws, w.tau);
  const V6 a0 = six(Eigen::Vector3d::Zero(), -m.gravity);
  const std::size_t nl = m.links.size();
  for (std::size_t i = 0; i < nl; ++i) {
    const LinkState<double>& L = ws[i];
    const int p = m.links[i].parent;
    if (ti[i] >= 0) {
      const V6 vp = p < 0 ? V6::Zero() : six(ws[p].vw, ws[p].vv);
      const V6 ap = p < 0 ? a0 : six(ws[p].aw, ws[p].av);
      const V6 S = axis_of(L);
      Eigen::Map<V6> psid(w.psi + 12 * ti[i]), psidd(w.psi + 12 * ti[i] + 6);
      psid = cross_motion(vp, S);
      psidd = cross_motion(ap, S) + cross_motion(vp, psid);
    }
    // B u = v ×* I u − I (v × u) + u ×* I v with the link's own inertia, in closed form: with
    // v = (ω, ν), I = [Ī [h]×; −[h]× m1] and I v = (p_n, p_f) = (Ī ω + h × ν, m ν + ω × h),
    //   B = [ [ω]× Ī − Ī [ω]× − [ν]×[h]× − [h]×[ν]× − [p_n]×   0 ]
    //       [ −2 [p_f]×                                         0 ]
    // ([ω]×[h]× − [h]×[ω]× = [ω × h]× cancels the top right; [a]×[b]× = b aᵀ − (a·b) 1). Only
    // its two left blocks are stored: B₁₁, B₂₁ (3 × 3 each).
    Eigen::Map<Eigen::Matrix3d> B11(w.B + 18 * static_cast<Index>(i)),
        B21(w.B + 18 * static_cast<Index>(i) + 9);
    const Eigen::Matrix3d Wx = skew(L.vw);
    const Eigen::Vector3d pn = L.I_own * L.vw + L.h_own.cross(L.vv);
    const Eigen::Vector3d pf = L.m_own * L.vv + L.vw.cross(L.h_own);
    B11.noalias() = Wx * L.I_own;
    B11.noalias() -= L.I_own * Wx;
    B11.noalias() -= L.h_own * L.vv.transpose() + L.vv * L.h_own.transpose();
    B11.diagonal().array() += 2.0 * L.h_own.dot(L.vv);
    B11 -= skew(pn);
    B21 = -2.0 * skew(pf);
  }
  for (std::size_t i = nl; i-- > 0;) {
    const int p = m.links[i].parent;
    if (p >= 0)
      Eigen::Map<Eigen::Matrix<double, 18, 1>>(w.B + 18 * static_cast<Index>(p)) +=
          Eigen::Map<const Eigen::Matrix<double, 18, 1>>(w.B + 18 * static_cast<Index>(i));
  }
}

// The entries of ∂τ/∂θ and ∂τ/∂θ̇ (the formulas above), joint j by joint: its column over its
// ancestors and itself, and its row over its strict ancestors.
void analytic_columns(const Model& m, const std::vector<int>& ti, Index nt,
                      const AnalyticWorkspace& w) {
  const LinkState<double>* ws = w.links;
  std::fill_n(w.Dq, 2 * nt * nt, 0.0);
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    const int j = ti[i];
    if (j < 0) continue;
    const LinkState<double>& L = ws[i];
    // Local copies (aligned): the sums in the products then do not depend on the slot's address.
    // B^C = [B₁₁ 0; B₂₁ 0] (analytic_passes) acts on a motion's angular part alone.
    const double* Bi = w.B + 18 * static_cast<Index>(i);
    const Eigen::Matrix3d B11 = Eigen::Map<const Eigen::Matrix3d>(Bi),
                          B21 = Eigen::Map<const Eigen::Matrix3d>(Bi + 9);
    const auto B_times = [&](const V6& u) -> V6 {
      const Eigen::Vector3d uw = u.head<3>();
      return six(B11 * uw, B21 * uw);
    };
    const V6 S = axis_of(L), F = six(L.fn, L.ff);
    const V6 psid = Eigen::Map<const V6>(w.psi + 12 * j),
             psidd = Eigen::Map<const V6>(w.psi + 12 * j + 6);
    const V6 fq = cross_force(S, F) + composite_times(L, psidd) + B_times(psid);
    const V6 fv = composite_times(L, 2.0 * psid) + B_times(S);
    const V6 U = composite_times(L, S),
             W = six(B11.transpose() * L.sw[0] + B21.transpose() * L.sv[0],
                     Eigen::Vector3d::Zero());
    for (int k = static_cast<int>(i); k >= 0; k = m.links[static_cast<std::size_t>(k)].parent) {
      const auto ku = static_cast<std::size_t>(k);
      const int r = ti[ku];
      if (r < 0) continue;
      const V6 Sk = axis_of(ws[ku]);
      w.Dq[r + j * nt] = Sk.dot(fq);
      w.Dqd[r + j * nt] = Sk.dot(fv);
      if (r == j) continue;
      const V6 kd = Eigen::Map<const V6>(w.psi + 12 * r),
               kdd = Eigen::Map<const V6>(w.psi + 12 * r + 6);
      w.Dq[j + r * nt] = U.dot(kdd) + W.dot(kd);
      w.Dqd[j + r * nt] = U.dot(2.0 * kd) + W.dot(Sk);
    }
  }
}

// c + Σ_t t.coefficient x(t.coordinate), summed in the terms' order.
double affine(const std::vector<Term>& terms, double c, CVecRef x) {
  for (const Term& t : terms) c += t.coefficient * x(t.coordinate);
  return c;
}

// θ = T q + c, θ̇ = T q̇, θ̈ = T q̈ into the analytic workspace.
void analytic_theta(const std::vector<std::vector<Term>>& T, const std::vector<double>& offset,
                    CVecRef q, CVecRef qd, CVecRef qdd, const AnalyticWorkspace& w) {
  for (std::size_t k = 0; k < T.size(); ++k) {
    w.theta[k] = affine(T[k], offset[k], q);
    w.thetad[k] = affine(T[k], 0.0, qd);
    w.thetadd[k] = affine(T[k], 0.0, qdd);
  }
}

bool same_bits(double a, double b) {
  return std::bit_cast<std::uint64_t>(a) == std::bit_cast<std::uint64_t>(b);
}

// The links inverse_dynamics_jacobian()'s analytic pass left in `placed` (a slot of `size`
// doubles) if `owner` left them there (the derivatives' key) at exactly these θ, θ̇, θ̈ (bitwise,
// computed as analytic_theta computes them: the same state gives the same bits), else null.
const LinkState<double>* analytic_links(ConstSlot placed, Index size, std::size_t nl, Index nt,
                                        const void* owner, const std::vector<std::vector<Term>>& T,
                                        const std::vector<double>& offset, CVecRef q, CVecRef qd,
                                        CVecRef qdd) {
  if (static_cast<Index>(placed.size()) != size) return nullptr;
  const double* key = placed.data() + workspace_doubles(nl, nt);
  if (key[1] != 1.0 || !same_bits(key[0], owner_tag(owner))) return nullptr;
  const double* base = placed.data() + derivative_offset(nl, nt);
  const double* th = base + static_cast<Index>(nl) * kLinkDoubles;
  for (std::size_t k = 0; k < T.size(); ++k) {
    const auto i = static_cast<Index>(k);
    if (!same_bits(th[i], affine(T[k], offset[k], q)) ||
        !same_bits(th[nt + i], affine(T[k], 0.0, qd)) ||
        !same_bits(th[2 * nt + i], affine(T[k], 0.0, qdd)))
      return nullptr;
  }
  return reinterpret_cast<const LinkState<double>*>(base);
}

// x (a 3-vector, or a 3 × 3 matrix row by row) times k added to column `col` of J from `row`.
void add_column(MatRef J, Index row, Index col, double k, const Eigen::Vector3d& x) {
  for (int r = 0; r < 3; ++r) J(row + r, col) += k * x(r);
}

void add_column(MatRef J, Index row, Index col, double k, const Eigen::Matrix3d& X) {
  for (int r = 0; r < 9; ++r) J(row + r, col) += k * X(r / 3, r % 3);
}

// A frame's derivatives along one joint variable, the columns of J (frame_state_jacobian's rows:
// p 0, R 3, ṗ 12, Ṙ 15, p̈ 24, R̈ 27): along q, ∂p, ∂R, ∂ṗ, ∂Ṙ, ∂p̈, ∂R̈; along q̇ (column n + c),
// ∂ṗ = ∂p, ∂Ṙ = ∂R and the rate parts of p̈, R̈.
struct VariableColumns {
  Eigen::Vector3d dp, q_pd, q_pdd, r_pdd;
  Eigen::Matrix3d dR, q_Rd, q_Rdd, r_Rdd;
};

// The columns of one term (coordinate c, coefficient k) of the variable added to J.
void add_term_columns(MatRef J, Index n, Index c, double k, const VariableColumns& v) {
  add_column(J, 0, c, k, v.dp);
  add_column(J, 3, c, k, v.dR);
  add_column(J, 12, c, k, v.q_pd);
  add_column(J, 15, c, k, v.q_Rd);
  add_column(J, 24, c, k, v.q_pdd);
  add_column(J, 27, c, k, v.q_Rdd);
  add_column(J, 12, n + c, k, v.dp);
  add_column(J, 15, n + c, k, v.dR);
  add_column(J, 24, n + c, k, v.r_pdd);
  add_column(J, 27, n + c, k, v.r_Rdd);
}

// A frame's derivatives from the same rigid transport (no scales, a_0 = 0 as frame_state's pass;
// links moved with a_0 = (0, a0) — inverse_dynamics_jacobian's, gravity — read less a0, their
// linear accelerations being a0 more than with a_0 = 0):
// along θ_j (joint j at or above the frame's link, axis S_j = (s_w, s_v)), the frame's p, R move
// by the column (s_v + s_w × p, [s_w]× R), the vectors and matrices it carries turn with s_w and
// the link's motion V = (ω, v_O) and acceleration A gain Ψ̇_j and Ψ̈_j + Ψ̇_j × V:
//   ∂ṗ = s_w × ṗ + ψ_v + ψ_w × p,        ∂Ṙ = [s_w]× Ṙ + [ψ_w]× R,
//   ∂p̈ = s_w × p̈ + α_v + α_w × p + ψ_w × ṗ + ω × (ψ_v + ψ_w × p),
//   ∂R̈ = [s_w]× R̈ + ([α_w]× + [ψ_w]×[ω]× + [ω]×[ψ_w]×) R     (ψ = Ψ̇_j, α = Ψ̈_j + Ψ̇_j × V);
// along θ̇_j, V gains S_j and A gains β = 2 Ψ̇_j + S_j × V: ṗ, Ṙ gain the column, and
//   ∂p̈ = β_v + β_w × p + s_w × ṗ + ω × ∂p/∂θ_j,   ∂R̈ = ([β_w]× + [s_w]×[ω]× + [ω]×[s_w]×) R.
void frame_motion_columns(const Model& m, const std::vector<int>& ti, const LinkState<double>* ws,
                          int link, const FrameMotion<double>& f, const Eigen::Vector3d& a0,
                          Index n, MatRef J) {
  const LinkState<double>& at = ws[link];
  const V6 V = six(at.vw, at.vv);
  const Eigen::Matrix3d W = skew<double>(at.vw);
  for (int j = link; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
    const auto ju = static_cast<std::size_t>(j);
    if (ti[ju] < 0) continue;
    const LinkState<double>& w = ws[ju];
    const int p = m.links[ju].parent;
    const V6 vp = p < 0 ? V6::Zero() : six(ws[p].vw, ws[p].vv);
    const V6 ap = p < 0 ? V6::Zero() : six(ws[p].aw, ws[p].av - a0);
    const V6 S = axis_of(w), psid = cross_motion(vp, S);
    const V6 al = cross_motion(ap, S) + cross_motion(vp, psid) + cross_motion(psid, V);
    const V6 be = 2.0 * psid + cross_motion(S, V);
    const Eigen::Vector3d sw = w.sw[0], pw = psid.head<3>(), aw = al.head<3>(), bw = be.head<3>();
    const Eigen::Vector3d dp = w.sv[0] + sw.cross(f.p), xv = psid.tail<3>() + pw.cross(f.p);
    const Eigen::Matrix3d Sw = skew<double>(sw), Pw = skew<double>(pw), dR = Sw * f.R;
    const Eigen::Vector3d q_pd = sw.cross(f.pd) + xv;
    const Eigen::Matrix3d q_Rd = Sw * f.Rd + Pw * f.R;
    const Eigen::Vector3d q_pdd =
        sw.cross(f.pdd) + al.tail<3>() + aw.cross(f.p) + pw.cross(f.pd) + at.vw.cross(xv);
    const Eigen::Matrix3d q_Rdd = Sw * f.Rdd + (skew<double>(aw) + Pw * W + W * Pw) * f.R;
    const Eigen::Vector3d r_pdd = be.tail<3>() + bw.cross(f.p) + sw.cross(f.pd) + at.vw.cross(dp);
    const Eigen::Matrix3d r_Rdd = (skew<double>(bw) + Sw * W + W * Sw) * f.R;
    for (const Term& t : m.links[ju].terms) {
      const Index c = t.coordinate;
      const double k = t.coefficient;
      add_term_columns(J, n, c, k, {dp, q_pd, q_pdd, r_pdd, dR, q_Rd, q_Rdd, r_Rdd});
    }
  }
}

// The derivatives of the frame's columns: ∂²p/∂θ_k∂θ_l = s_w,k × (s_v,l + s_w,l × p) and
// ∂²R/∂θ_k∂θ_l = [s_w,k]× [s_w,l]× R for k at or above l (symmetric), through θ = T q + c.
void frame_column_columns(const Model& m, const std::vector<int>& ti, const LinkState<double>* ws,
                          int link, const FrameMotion<double>& f, MatRef J) {
  for (int l = link; l >= 0; l = m.links[static_cast<std::size_t>(l)].parent) {
    const auto lu = static_cast<std::size_t>(l);
    if (ti[lu] < 0) continue;
    const Eigen::Vector3d dp = ws[lu].sv[0] + ws[lu].sw[0].cross(f.p);
    const Eigen::Matrix3d dR = skew<double>(ws[lu].sw[0]) * f.R;
    for (int k = l; k >= 0; k = m.links[static_cast<std::size_t>(k)].parent) {
      const auto ku = static_cast<std::size_t>(k);
      if (ti[ku] < 0) continue;
      const Eigen::Vector3d hp = ws[ku].sw[0].cross(dp);
      const Eigen::Matrix3d hR = skew<double>(ws[ku].sw[0]) * dR;
      for (const Term& a : m.links[ku].terms) {
        for (const Term& b : m.links[lu].terms) {
          const double c = a.coefficient * b.coefficient;
          add_column(J, 36 + 12 * a.coordinate, b.coordinate, c, hp);
          add_column(J, 39 + 12 * a.coordinate, b.coordinate, c, hR);
          if (k == l) continue;
          add_column(J, 36 + 12 * b.coordinate, a.coordinate, c, hp);
          add_column(J, 39 + 12 * b.coordinate, a.coordinate, c, hR);
        }
      }
    }
  }
}

// ------------------------------------------- analytic derivatives of the RNEA with ball joints
//
// The same recursion (Carpentier & Mansard 2018, §III–IV) on the similarity motions of the
// quaternion joints (docs/tree-algorithms.md, "Quaternion joints"): motions X = (ω, λ, v_O) with
// the bracket [X, Y] of joint_motion, forces F = (n, e, f) paired as ω·n + λ e + v·f, and the dual
// action X ×* F = (ω × n + v × f, v · f, ω × f − λ f) (⟨Y, X ×* F⟩ = −⟨[X, Y], F⟩). A change of a
// joint variable θ_a of joint J moves J's link and its subtree by the similarity generated by T =
// S_a (the rotation, the scale's rate λ_T and the translation): world motions below change by
// [T, X], points by T(x) = v_T + ω_T × x + λ_T x, and the links' forces by T ×* F + 2 λ_T F (the
// symbolic kinetic energy grows as the square of the scale). What is not carried along is, for
// every link i at or below J,
//   δV_i = [T, V_i] + P,   δA_i = [T, A_i] + Q + [P, V_i],
//   P = [V_λ(J), T] + Σ_k (∂S_k/∂θ_a − [T, S_k]) θ̇_k,
//   Q = [A_λ(J), T] + δJ − [T, J] − [P, V_J]    (J = A_J − A_λ(J), δJ its change along θ_a),
// the sums over J's own variables k: their axes ∂S_k/∂θ_a are the paper's ∂S/∂q of a multi-degree
// of freedom joint (its Eq. (8) with the motion subspace S(q) of a spherical joint, here the four
// quaternion axes of place_ball: ω = 2 G(u) u̇ / |u|², λ = 2 u·u̇ / |u|²), zero for a revolute or
// prismatic joint, whose P and Q reduce to Ψ̇, Ψ̈ of the analytic pass above; along θ̇_a nothing
// moves, P = S_a and Q = [V_λ(J), S_a] + ∂B_J/∂θ̇_a − [S_a, V_J] (B_J: the ball's own axis rate,
// joint_motion). A link's force f = Φ(c, I_c, V, A) (link_force) then changes by the transport
// plus I Q + B P, B X = I [X, V] + ∂Φ/∂V X, and, with the composites I^C, B^C and the subtree
// forces F,
//   ∂τ_k/∂θ_a = ⟨S_k, T ×* F_J + 2 λ_T F_J + I^C_J Q + B^C_J P⟩ + ⟨∂S_k/∂θ_a, F_J⟩   (k at or above J),
//             = 2 λ_T ⟨S_k, F_K⟩ + ⟨S_k, I^C_K Q + B^C_K P⟩                       (K below J),
// ∂τ/∂θ̇ the same with T = 0. The correction terms of rate_scale_terms are differentiated along
// the same transport (rate_scale_derivative below).

using V7 = Eigen::Matrix<double, 7, 1>;
using M7 = Eigen::Matrix<double, 7, 7>;

V7 seven(const Eigen::Vector3d& w, double l, const Eigen::Vector3d& v) {
  V7 x;
  x << w, l, v;
  return x;
}

Eigen::Vector3d ang(const V7& x) { return x.head<3>(); }
Eigen::Vector3d lin(const V7& x) { return x.tail<3>(); }

V7 axis7(const LinkState<double>& w, int k) { return seven(w.sw[k], w.sl[k], w.sv[k]); }
V7 velocity7(const LinkState<double>& w) { return seven(w.vw, w.vl, w.vv); }
V7 acceleration7(const LinkState<double>& w) { return seven(w.aw, w.al, w.av); }
V7 force7(const LinkState<double>& w) { return seven(w.fn, w.fe, w.ff); }

// [(ω1, λ1, v1), (ω2, λ2, v2)] = (ω1 × ω2, 0, ω1 × v2 + λ1 v2 − ω2 × v1 − λ2 v1) (joint_motion).
V7 bracket(const V7& a, const V7& b) {
  const Eigen::Vector3d aw = ang(a), av = lin(a), bw = ang(b), bv = lin(b);
  return seven(aw.cross(bw), 0.0, aw.cross(bv) + a(3) * bv - bw.cross(av) - b(3) * av);
}

V7 cross_force7(const V7& a, const V7& F) {
  const Eigen::Vector3d aw = ang(a), av = lin(a), n = ang(F), f = lin(F);
  return seven(aw.cross(n) + av.cross(f), av.dot(f), aw.cross(f) - a(3) * f);
}

// (n, e, f) = I (ω, λ, v) for the inertia (m, h, Ī, k) (crba's, with the scale's k).
V7 inertia7(double m, const Eigen::Vector3d& h, const Eigen::Matrix3d& I, double k, const V7& u) {
  Eigen::Vector3d n, f;
  apply_inertia<double>(m, h, I, ang(u), lin(u), n, f);
  return seven(n, h.dot(lin(u)) + k * u(3), f + h * u(3));
}

V7 composite7(const LinkState<double>& w, const V7& u) { return inertia7(w.m, w.h, w.I, w.k, u); }

// ∂Φ/∂V x: the change of link_force's (n, e, f) with the link's velocity along x (c and I_c fixed).
V7 velocity_force(const Link& L, const LinkState<double>& w, const V7& x) {
  if (L.mass == 0.0 && L.inertia.isZero(0.0)) return V7::Zero();
  const Eigen::Vector3d xw = ang(x), cd = w.vv + w.vw.cross(w.c) + w.c * w.vl;
  const Eigen::Vector3d dcd = lin(x) + xw.cross(w.c) + w.c * x(3);
  const Eigen::Vector3d f = (xw.cross(cd) + w.vw.cross(dcd) + cd * x(3) + dcd * w.vl) * w.m_own;
  const Eigen::Vector3d n = w.c.cross(f) + xw.cross(Eigen::Vector3d(w.Ic * w.vw)) +
                            w.vw.cross(Eigen::Vector3d(w.Ic * xw));
  return seven(n, w.c.dot(f), f);
}

// The space-frame rate matrix's columns g_k(u) (place_ball), linear in u.
void rate_columns(const double* u, Eigen::Vector3d g[4]) {
  g[0] = {-u[1], -u[2], -u[3]};
  g[1] = {u[0], u[3], -u[2]};
  g[2] = {-u[3], u[0], u[1]};
  g[3] = {u[2], -u[1], u[0]};
}

// ∂S_k/∂u_l of a ball joint's axes (place_ball: ω_k = Rw g_k(u), Rw = R_j (2/|u|²) / sc, λ_k =
// 2 u_k / |u|², v_k = p × ω_k − λ_k p): with qs = 2/|u|², ∂qs/∂u_l = −qs² u_l and, since
// G(u) G(u)ᵀ = |u|² 1, Rw = Σ_k ω_k g_k(u)ᵀ / |u|².
void ball_axis_derivatives(const LinkState<double>& w, const double* u, int l, V7 dS[4]) {
  Eigen::Vector3d g[4], e[4];
  rate_columns(u, g);
  double unit[4] = {0.0, 0.0, 0.0, 0.0};
  unit[l] = 1.0;
  rate_columns(unit, e);
  Eigen::Matrix3d Rw = Eigen::Matrix3d::Zero();
  for (int k = 0; k < 4; ++k) Rw += w.sw[k] * g[k].transpose();
  Rw *= 0.5 * w.qs;  // 1 / |u|²
  for (int k = 0; k < 4; ++k) {
    const Eigen::Vector3d dw = Rw * e[k] - w.sw[k] * (w.qs * u[l]);
    const double dl = (k == l ? w.qs : 0.0) - w.qs * w.qs * u[k] * u[l];
    dS[k] = seven(dw, dl, w.p.cross(dw) - w.p * dl);
  }
}

// The ball joint's own axis rate B_J = (−λ ω_j, |u̇|² qs − λ², about p) (joint_motion; ω_j = Σ ω_k
// u̇_k, λ = Σ λ_k u̇_k) differentiated along u_l (rate false: with ∂S_k/∂u_l in dS) or along u̇_l.
V7 ball_rate_derivative(const LinkState<double>& w, const double* u, const double* ud, int l,
                        const V7* dS, bool rate) {
  Eigen::Vector3d jw = Eigen::Vector3d::Zero(), djw = Eigen::Vector3d::Zero();
  double jl = 0.0, djl = 0.0, ud2 = 0.0;
  for (int k = 0; k < 4; ++k) {
    jw += w.sw[k] * ud[k];
    jl += w.sl[k] * ud[k];
    ud2 += ud[k] * ud[k];
    if (!rate) {
      djw += ang(dS[k]) * ud[k];
      djl += dS[k](3) * ud[k];
    }
  }
  double dal = 0.0;
  if (rate) {
    djw = w.sw[l];
    djl = w.sl[l];
    dal = 2.0 * ud[l] * w.qs - 2.0 * jl * djl;
  } else {
    dal = -ud2 * w.qs * w.qs * u[l] - 2.0 * jl * djl;
  }
  const Eigen::Vector3d daw = -(djw * jl + jw * djl);
  return seven(daw, dal, w.p.cross(daw) - w.p * dal);
}

// Per link: Λ (Σ λ_b of the ball joints at or above it) and Qm (Σ λ_b Ir_b over the ball joints b
// of its subtree, Ir_b their subtree's Σ I_c), after rate_scale_terms: 10 doubles.
double path_scale(const AnalyticWorkspace& w, int link) {
  return link < 0 ? 0.0 : w.ext[10 * static_cast<Index>(link)];
}

Eigen::Map<const Eigen::Matrix3d> scale_inertia(const AnalyticWorkspace& w, std::size_t link) {
  return Eigen::Map<const Eigen::Matrix3d>(w.ext + 10 * static_cast<Index>(link) + 1);
}

Eigen::Vector3d path_rates(const LinkState<double>* ws, int link) {  // Y of the parent
  return link < 0 ? Eigen::Vector3d::Zero() : ws[link].Y;
}

// The directions of joint variable a + l of link i (joint J): P, Q along θ, Q along θ̇ and δλ_J
// along θ (22 doubles per variable, the formulas above).
void quaternion_directions(const Model& m, const std::vector<int>& ti, const AnalyticWorkspace& w,
                           std::size_t i, const V7& a0) {
  const LinkState<double>* ws = w.links;
  const LinkState<double>& s = ws[i];
  const int p = m.links[i].parent, a = ti[i], nv = variables(m.links[i].type);
  const bool ball = m.links[i].type == JointType::ball;
  const V7 Vp = p < 0 ? V7::Zero() : velocity7(ws[p]), Ap = p < 0 ? a0 : acceleration7(ws[p]);
  const V7 VJ = velocity7(s), Jp = acceleration7(s) - Ap;
  const double *u = w.theta + a, *ud = w.thetad + a, *udd = w.thetadd + a;
  for (int l = 0; l < nv; ++l) {
    const V7 T = axis7(s, l);
    V7 P = bracket(Vp, T), dJ = V7::Zero(), Qd = bracket(Vp, T) - bracket(T, VJ);
    double dlam = 0.0;
    if (ball) {
      V7 dS[4];
      ball_axis_derivatives(s, u, l, dS);
      for (int k = 0; k < 4; ++k) {
        P += (dS[k] - bracket(T, axis7(s, k))) * ud[k];
        dJ += dS[k] * udd[k] + bracket(Vp, dS[k]) * ud[k];
        dlam += dS[k](3) * ud[k];
      }
      dJ += ball_rate_derivative(s, u, ud, l, dS, false);
      Qd += ball_rate_derivative(s, u, ud, l, dS, true);
    }
    double* d = w.psi + 22 * (a + l);
    Eigen::Map<V7> P_out(d), Q_out(d + 7), Qd_out(d + 14);
    P_out = P;
    Q_out = bracket(Ap, T) + dJ - bracket(T, Jp) - bracket(P, VJ);
    Qd_out = Qd;
    d[21] = dlam;
  }
}

// With ball joints: the RNEA on doubles (gravity as a_0), each link's own B (then B^C), Λ and Qm,
// and each variable's directions.
void quaternion_passes(const Model& m, const std::vector<int>& ti, const AnalyticWorkspace& w) {
  LinkState<double>* ws = w.links;
  place<double>(m, ti, true, w.theta, ws);
  composite<double>(m, ws);
  inverse_dynamics<double>(m, ti, true, w.thetad, w.thetadd, true, ws, w.tau);
  const V7 a0 = seven(Eigen::Vector3d::Zero(), 0.0, -m.gravity);
  const std::size_t nl = m.links.size();
  for (std::size_t i = 0; i < nl; ++i) {
    const Link& L = m.links[i];
    const LinkState<double>& s = ws[i];
    const bool ball = L.type == JointType::ball;
    double* ext = w.ext + 10 * static_cast<Index>(i);
    ext[0] = path_scale(w, L.parent) + (ball ? s.lj : 0.0);
    Eigen::Map<Eigen::Matrix3d>(ext + 1) =
        ball ? Eigen::Matrix3d(s.Ir * s.lj) : Eigen::Matrix3d::Zero();
    Eigen::Map<M7> B(w.B + 49 * static_cast<Index>(i));
    const V7 V = velocity7(s);
    for (int c = 0; c < 7; ++c) {
      const V7 x = V7::Unit(c);
      B.col(c) =
          inertia7(s.m_own, s.h_own, s.I_own, s.k_own, bracket(x, V)) + velocity_force(L, s, x);
    }
    if (ti[i] >= 0) quaternion_directions(m, ti, w, i, a0);
  }
  for (std::size_t i = nl; i-- > 0;) {
    const int p = m.links[i].parent;
    if (p < 0) continue;
    Eigen::Map<M7>(w.B + 49 * static_cast<Index>(p)) +=
        Eigen::Map<const M7>(w.B + 49 * static_cast<Index>(i));
    Eigen::Map<Eigen::Matrix3d>(w.ext + 10 * static_cast<Index>(p) + 1) += scale_inertia(w, i);
  }
}

// One direction (joint J, link j) as the correction terms of rate_scale_terms see it: the
// transport (ω_T, λ_T; zero along θ̇), P's rotation pw, δλ_J, and the changes of J's subtree's
// Ir, H and Z (the formulas of rate_scale_derivative).
struct ScaleDirection {
  Eigen::Vector3d wt, pw, dH, dZ;
  double lt = 0.0, dlam = 0.0;
  Eigen::Matrix3d dIr;
};

ScaleDirection scale_direction(const Model& m, const AnalyticWorkspace& w, std::size_t j,
                               const V7& T, const Eigen::Vector3d& pw, double dlam) {
  const LinkState<double>& s = w.links[j];
  ScaleDirection d;
  d.wt = ang(T);
  d.lt = T(3);
  d.pw = pw;
  d.dlam = dlam;
  const Eigen::Matrix3d W = skew<double>(d.wt);
  d.dIr = W * s.Ir - s.Ir * W + 2.0 * d.lt * s.Ir;
  d.dH = d.wt.cross(s.H) + 2.0 * d.lt * s.H + s.Ir * pw;
  d.dZ = d.wt.cross(s.Z) + 2.0 * d.lt * s.Z + 2.0 * (scale_inertia(w, j) * pw);
  if (m.links[j].type == JointType::ball) d.dZ += dlam * (s.H + s.Ir * s.vw);
  return d;
}

// The change of the correction terms (rate_scale_terms) of joint K (link k, variable kk) at or above
// J (link j) along direction d of J: Δτ = ω_kk · (Z_K + Ir_K Y_λ(K)) − [K ball] λ_kk ω_K · H_K, with
// Z_K gaining d.dZ and, through the ball joints b between K and J (Λ, Y of the parents), λ_b (δH
// + δIr ω_b); dS: ∂S_kk/∂θ when K is J (a ball joint, along its own θ), else null.
double rate_above(const Model& m, const AnalyticWorkspace& w, std::size_t j, std::size_t k, int kk,
                  const ScaleDirection& d, const V7* dS) {
  const LinkState<double>* ws = w.links;
  const LinkState<double>& K = ws[k];
  const int pj = m.links[j].parent, pk = m.links[k].parent;
  const Eigen::Vector3d YK = path_rates(ws, pk);
  const Eigen::Vector3d dZ =
      d.dZ + (path_scale(w, pj) - path_scale(w, pk)) * d.dH + d.dIr * (path_rates(ws, pj) - YK);
  double r = K.sw[kk].dot(dZ + d.dIr * YK);
  if (dS) r += ang(*dS).dot(K.Z + K.Ir * YK);
  if (m.links[k].type == JointType::ball) {
    const Eigen::Vector3d dw =
        k == j ? Eigen::Vector3d(d.wt.cross(K.vw) + d.pw) : Eigen::Vector3d::Zero();
    r -= (dS ? (*dS)(3) : 0.0) * K.vw.dot(K.H) + K.sl[kk] * (dw.dot(K.H) + K.vw.dot(d.dH));
  }
  return r;
}

// The same for joint variable l of link i strictly below K (link k), along a direction of K with
// transport T (zero along θ̇), P's rotation pw and δλ_K: every term of i's subtree is carried
// (its rotations cancel in the products), what remains is the scale's 2 λ_T, Qm and Ir times P,
// and Y_λ(i)'s non-carried part (−ω_T × Y_λ(K) + δλ_K ω_K + (Λ_λ(i) − Λ_λ(K)) pw).
double rate_below(const Model& m, const AnalyticWorkspace& w, std::size_t k, std::size_t i, int l,
                  const V7& T, const Eigen::Vector3d& pw, double dlam) {
  const LinkState<double>* ws = w.links;
  const LinkState<double>& s = ws[i];
  const int pi = m.links[i].parent, pk = m.links[k].parent;
  const double lt = T(3);
  Eigen::Vector3d y =
      -ang(T).cross(path_rates(ws, pk)) + (path_scale(w, pi) - path_scale(w, pk)) * pw;
  if (m.links[k].type == JointType::ball) y += dlam * ws[k].vw;
  const Eigen::Vector3d t = 2.0 * lt * s.Z + 2.0 * (scale_inertia(w, i) * pw) +
                            2.0 * lt * (s.Ir * path_rates(ws, pi)) + s.Ir * y;
  double r = s.sw[l].dot(t);
  if (m.links[i].type == JointType::ball)
    r -= s.sl[l] * (pw.dot(s.H) + 2.0 * lt * s.vw.dot(s.H) + s.vw.dot(s.Ir * pw));
  return r;
}

// The entries of joint J's column (its variables' directions on the torques at or above it).
void quaternion_column(const Model& m, const std::vector<int>& ti, Index nt,
                       const AnalyticWorkspace& w, std::size_t j) {
  const LinkState<double>* ws = w.links;
  const LinkState<double>& s = ws[j];
  const bool ball = m.links[j].type == JointType::ball;
  const M7 B = Eigen::Map<const M7>(w.B + 49 * static_cast<Index>(j));
  const V7 F = force7(s);
  for (int l = 0; l < variables(m.links[j].type); ++l) {
    const Index a = ti[j] + l;
    const V7 T = axis7(s, l);
    const double* d = w.psi + 22 * a;
    const V7 P = Eigen::Map<const V7>(d), Q = Eigen::Map<const V7>(d + 7),
             Qd = Eigen::Map<const V7>(d + 14);
    V7 dS[4];
    if (ball) ball_axis_derivatives(s, w.theta + ti[j], l, dS);
    const V7 X = cross_force7(T, F) + 2.0 * T(3) * F + composite7(s, Q) + B * P;
    const V7 Xd = composite7(s, Qd) + B * T;
    const ScaleDirection sq = scale_direction(m, w, j, T, ang(P), d[21]);
    const ScaleDirection sd = scale_direction(m, w, j, V7::Zero(), ang(T), ball ? s.sl[l] : 0.0);
    for (int k = static_cast<int>(j); k >= 0; k = m.links[static_cast<std::size_t>(k)].parent) {
      const auto ku = static_cast<std::size_t>(k);
      if (ti[ku] < 0) continue;
      for (int kk = 0; kk < variables(m.links[ku].type); ++kk) {
        const Index r = ti[ku] + kk;
        const V7 S = axis7(ws[ku], kk);
        const V7* own = ku == j && ball ? &dS[kk] : nullptr;
        w.Dq[r + a * nt] =
            S.dot(X) + (own ? own->dot(F) : 0.0) + rate_above(m, w, j, ku, kk, sq, own);
        w.Dqd[r + a * nt] = S.dot(Xd) + rate_above(m, w, j, ku, kk, sd, nullptr);
      }
    }
  }
}

// The entries of joint J's row along the directions of its strict ancestors K.
void quaternion_row(const Model& m, const std::vector<int>& ti, Index nt,
                    const AnalyticWorkspace& w, std::size_t j) {
  const LinkState<double>* ws = w.links;
  const LinkState<double>& s = ws[j];
  const M7 B = Eigen::Map<const M7>(w.B + 49 * static_cast<Index>(j));
  const V7 F = force7(s);
  for (int l = 0; l < variables(m.links[j].type); ++l) {
    const Index a = ti[j] + l;
    const V7 Sl = axis7(s, l), U = composite7(s, Sl), W = B.transpose() * Sl;
    const double tr = Sl.dot(F);
    for (int k = m.links[j].parent; k >= 0; k = m.links[static_cast<std::size_t>(k)].parent) {
      const auto ku = static_cast<std::size_t>(k);
      if (ti[ku] < 0) continue;
      const bool ball = m.links[ku].type == JointType::ball;
      for (int kk = 0; kk < variables(m.links[ku].type); ++kk) {
        const Index r = ti[ku] + kk;
        const double* d = w.psi + 22 * r;
        const V7 T = axis7(ws[ku], kk), P = Eigen::Map<const V7>(d),
                 Q = Eigen::Map<const V7>(d + 7), Qd = Eigen::Map<const V7>(d + 14);
        w.Dq[a + r * nt] =
            2.0 * T(3) * tr + U.dot(Q) + W.dot(P) + rate_below(m, w, ku, j, l, T, ang(P), d[21]);
        w.Dqd[a + r * nt] =
            U.dot(Qd) + W.dot(T) +
            rate_below(m, w, ku, j, l, V7::Zero(), ang(T), ball ? ws[ku].sl[kk] : 0.0);
      }
    }
  }
}

void quaternion_columns(const Model& m, const std::vector<int>& ti, Index nt,
                        const AnalyticWorkspace& w) {
  std::fill_n(w.Dq, 2 * nt * nt, 0.0);
  for (std::size_t j = 0; j < m.links.size(); ++j) {
    if (ti[j] < 0) continue;
    quaternion_column(m, ti, nt, w, j);
    quaternion_row(m, ti, nt, w, j);
  }
}

// A frame's derivatives with ball joints, from the same transport as quaternion_columns: along
// θ_a of joint J (T = S_a, P, Q of quaternion_directions at a_0 = 0), the frame's p, R move by
// T(p) = v_T + ω_T × p + λ_T p and (Tm) R (Tm = [ω_T]× + λ_T), its rates and accelerations turn
// and scale with Tm and gain the link's P and X = Q + [P, V] (V = (ω, λ, v_O) the link's motion,
// W = [ω]× + λ, Pm, Xm as Tm):
//   ∂ṗ = Tm ṗ + P(p),            ∂Ṙ = Tm Ṙ + Pm R,
//   ∂p̈ = Tm p̈ + X(p) + Pm ṗ + W P(p),   ∂R̈ = Tm R̈ + (Xm + W Pm + Pm W) R;
// along θ̇_a (nothing carried, P = S_a, X = Q̇ + [S_a, V]) ṗ, Ṙ gain the column and
//   ∂p̈ = X(p) + Tm ṗ + W T(p),   ∂R̈ = (Xm + W Tm + Tm W) R.
Eigen::Vector3d at_point(const V7& x, const Eigen::Vector3d& p) {
  return lin(x) + ang(x).cross(p) + x(3) * p;
}

Eigen::Matrix3d rate_matrix(const V7& x) {
  return skew<double>(ang(x)) + x(3) * Eigen::Matrix3d::Identity();
}

void quaternion_frame_columns(const Model& m, const std::vector<int>& ti,
                              const AnalyticWorkspace& w, int link, const FrameMotion<double>& f,
                              Index n, MatRef J) {
  const LinkState<double>& at = w.links[link];
  const V7 V = velocity7(at);
  const Eigen::Matrix3d W = rate_matrix(V);
  for (int j = link; j >= 0; j = m.links[static_cast<std::size_t>(j)].parent) {
    const auto ju = static_cast<std::size_t>(j);
    if (ti[ju] < 0) continue;
    const Link& L = m.links[ju];
    for (int l = 0; l < variables(L.type); ++l) {
      const double* d = w.psi + 22 * (ti[ju] + l);
      const V7 T = axis7(w.links[ju], l), P = Eigen::Map<const V7>(d);
      const V7 X = Eigen::Map<const V7>(d + 7) + bracket(P, V);
      const V7 Xd = Eigen::Map<const V7>(d + 14) + bracket(T, V);
      const Eigen::Matrix3d Tm = rate_matrix(T), Pm = rate_matrix(P);
      const Eigen::Vector3d dp = at_point(T, f.p), Pp = at_point(P, f.p);
      const Eigen::Matrix3d dR = Tm * f.R;
      const Eigen::Vector3d q_pd = Tm * f.pd + Pp;
      const Eigen::Matrix3d q_Rd = Tm * f.Rd + Pm * f.R;
      const Eigen::Vector3d q_pdd = Tm * f.pdd + at_point(X, f.p) + Pm * f.pd + W * Pp;
      const Eigen::Matrix3d q_Rdd = Tm * f.Rdd + (rate_matrix(X) + W * Pm + Pm * W) * f.R;
      const Eigen::Vector3d r_pdd = at_point(Xd, f.p) + Tm * f.pd + W * dp;
      const Eigen::Matrix3d r_Rdd = (rate_matrix(Xd) + W * Tm + Tm * W) * f.R;
      const auto [first, last] = variable_terms(L, l);
      for (const Term* t = first; t != last; ++t) {
        const Index c = t->coordinate;
        const double k = t->coefficient;
        add_term_columns(J, n, c, k, {dp, q_pd, q_pdd, r_pdd, dR, q_Rd, q_Rdd, r_Rdd});
      }
    }
  }
}

// ∂²x/∂θ_k∂θ_b (x = p, R) added as column k's change along coordinate direction of b and, when
// `both`, column b's along k (the mixed derivatives are symmetric), through θ = T q + c.
void add_second(const Link& K, int k, const Link& Lb, int b, bool both, const Eigen::Vector3d& hp,
                const Eigen::Matrix3d& hR, MatRef J) {
  const auto [k0, k1] = variable_terms(K, k);
  const auto [b0, b1] = variable_terms(Lb, b);
  for (const Term* x = k0; x != k1; ++x) {
    for (const Term* y = b0; y != b1; ++y) {
      const double c = x->coefficient * y->coefficient;
      add_column(J, 36 + 12 * x->coordinate, y->coordinate, c, hp);
      add_column(J, 39 + 12 * x->coordinate, y->coordinate, c, hR);
      if (!both) continue;
      add_column(J, 36 + 12 * y->coordinate, x->coordinate, c, hp);
      add_column(J, 39 + 12 * y->coordinate, x->coordinate, c, hR);
    }
  }
}

// The derivatives of the frame's columns S_k(p), (Sm_k) R: for k of a joint above b's,
// ∂²p/∂θ_k∂θ_b = Sm_k S_b(p) and ∂²R/∂θ_k∂θ_b = Sm_k Sm_b R; within a ball joint also the axes'
// own change, ∂S_k/∂u_b (p) and (∂Sm_k/∂u_b) R.
void quaternion_frame_column_columns(const Model& m, const std::vector<int>& ti,
                                     const AnalyticWorkspace& w, int link,
                                     const FrameMotion<double>& f, MatRef J) {
  for (int l = link; l >= 0; l = m.links[static_cast<std::size_t>(l)].parent) {
    const auto lu = static_cast<std::size_t>(l);
    if (ti[lu] < 0) continue;
    const Link& L = m.links[lu];
    const LinkState<double>& s = w.links[lu];
    for (int b = 0; b < variables(L.type); ++b) {
      const V7 Sb = axis7(s, b);
      const Eigen::Vector3d dp = at_point(Sb, f.p);
      const Eigen::Matrix3d Mb = rate_matrix(Sb);
      if (L.type == JointType::ball) {
        V7 dS[4];
        ball_axis_derivatives(s, w.theta + ti[lu], b, dS);
        for (int k = 0; k < 4; ++k) {
          const Eigen::Matrix3d Mk = rate_matrix(axis7(s, k));
          add_second(L, k, L, b, false, at_point(dS[k], f.p) + Mk * dp,
                     (rate_matrix(dS[k]) + Mk * Mb) * f.R, J);
        }
      } else {
        add_second(L, b, L, b, false, Mb * dp, Mb * Mb * f.R, J);
      }
      for (int k = L.parent; k >= 0; k = m.links[static_cast<std::size_t>(k)].parent) {
        const auto ku = static_cast<std::size_t>(k);
        if (ti[ku] < 0) continue;
        for (int kk = 0; kk < variables(m.links[ku].type); ++kk) {
          const Eigen::Matrix3d Mk = rate_matrix(axis7(w.links[ku], kk));
          add_second(m.links[ku], kk, L, b, true, Mk * dp, Mk * Mb * f.R, J);
        }
      }
    }
  }
}

}  // namespace

// ∂ID/∂q = Tᵀ (∂τ_θ/∂θ) T and ∂ID/∂q̇ = Tᵀ (∂τ_θ/∂θ̇) T at θ̈ = T q̈ by the analytic pass (one
// forward and one backward recursion for every column; docs/derivatives.md, "Cost"): the rigid one
// without ball joints (its links then left in the slot for frame_state_jacobian), the one on
// similarity motions with the correction terms with them. [[gnu::flatten]] as
// frame_state_jacobian.
[[gnu::flatten]] bool TreeSubsystem::inverse_dynamics_jacobian(const EvalContext& c, CVecRef q,
                                                               CVecRef qd, CVecRef qdd,
                                                               MatRef dID_dq,
                                                               MatRef dID_dqd) const {
  const std::size_t nl = merged_.links.size();
  std::vector<double> own;
  const AnalyticWorkspace w = analytic_workspace(c.slot, slot_size_, nl, n_theta_, own);
  analytic_theta(theta_terms_, theta_offset_, q, qd, qdd, w);
  if (quaternions_) {
    quaternion_passes(merged_, theta_index_, w);
    quaternion_columns(merged_, theta_index_, n_theta_, w);
    to_coordinates(theta_terms_, w.Dq, dID_dq);
    to_coordinates(theta_terms_, w.Dqd, dID_dqd);
    return true;
  }
  analytic_passes(merged_, theta_index_, w);
  analytic_columns(merged_, theta_index_, n_theta_, w);
  if (w.key) {  // the links placed and moved at this state: frame_state_jacobian reads them
    w.key[0] = owner_tag(this);
    w.key[1] = 1.0;
  }
  to_coordinates(theta_terms_, w.Dq, dID_dq);
  to_coordinates(theta_terms_, w.Dqd, dID_dqd);
  return true;
}

// Without ball joints: the analytic columns on the links inverse_dynamics_jacobian() left in
// `placed` at this state (no placement, no motion pass: its accelerations less a_0 = −g), else on
// one placement and motion pass on doubles in `scratch`; with ball joints, the analytic columns on
// similarity motions after one placement and motion pass in `scratch`. [[gnu::flatten]]: every
// call inlined (the chains' frame columns measured 7–10 % slower without it).
[[gnu::flatten]] void TreeSubsystem::frame_state_jacobian(CVecRef q, CVecRef qd, CVecRef qdd,
                                                          int frame_link,
                                                          const Eigen::Matrix3d& frame_R_offset,
                                                          const Eigen::Vector3d& frame_x_offset,
                                                          ConstSlot placed, Slot scratch,
                                                          FrameState& value, MatRef J) const {
  int link = -1;
  Eigen::Matrix3d R_offset = frame_R_offset;
  Eigen::Vector3d x_offset = frame_x_offset;
  on_merged(placement_, frame_link, link, R_offset, x_offset);
  const Index n = dof();
  std::vector<double> own;
  J.setZero();
  value.dp.setZero();
  value.dR.setZero();
  if (!quaternions_) {  // the analytic columns (frame_motion_columns, frame_column_columns)
    const std::size_t nl = merged_.links.size();
    const LinkState<double>* links = analytic_links(placed, slot_size_, nl, n_theta_, this,
                                                    theta_terms_, theta_offset_, q, qd, qdd);
    Eigen::Vector3d a0 = Eigen::Vector3d::Zero();  // the links' a_0 (linear part)
    if (links) {
      a0 = -merged_.gravity;
    } else {
      const AnalyticWorkspace a = analytic_workspace(scratch, slot_size_, nl, n_theta_, own);
      analytic_theta(theta_terms_, theta_offset_, q, qd, qdd, a);
      place<double>(merged_, theta_index_, false, a.theta, a.links);
      link_motion<double>(merged_, theta_index_, false, a.thetad, a.thetadd, a0, a.links);
      links = a.links;
    }
    FrameMotion<double> f = frame_motion(merged_, links, link, R_offset, x_offset);
    if (link >= 0) f.pdd -= a0;  // p̈ is linear in the link's a_O, with coefficient 1
    copy_state(merged_, theta_index_, links, link, f, value);
    if (link < 0) return;
    frame_motion_columns(merged_, theta_index_, links, link, f, a0, n, J);
    frame_column_columns(merged_, theta_index_, links, link, f, J);
    return;
  }
  // With ball joints: one placement and motion pass on doubles (a_0 = 0), the directions of the
  // joints above the frame, then the columns.
  const AnalyticWorkspace a =
      analytic_workspace(scratch, slot_size_, merged_.links.size(), n_theta_, own);
  analytic_theta(theta_terms_, theta_offset_, q, qd, qdd, a);
  place<double>(merged_, theta_index_, true, a.theta, a.links);
  link_motion<double>(merged_, theta_index_, true, a.thetad, a.thetadd, Eigen::Vector3d::Zero(),
                      a.links);
  const FrameMotion<double> f = frame_motion(merged_, a.links, link, R_offset, x_offset);
  copy_state(merged_, theta_index_, a.links, link, f, value);
  if (link < 0) return;
  for (int j = link; j >= 0; j = merged_.links[static_cast<std::size_t>(j)].parent) {
    if (theta_index_[static_cast<std::size_t>(j)] >= 0)
      quaternion_directions(merged_, theta_index_, a, static_cast<std::size_t>(j), V7::Zero());
  }
  quaternion_frame_columns(merged_, theta_index_, a, link, f, n, J);
  quaternion_frame_column_columns(merged_, theta_index_, a, link, f, J);
}

std::shared_ptr<const TreeSubsystem> make_subsystem(Model model) {
  return std::make_shared<TreeSubsystem>(std::move(model));
}

}  // namespace ukdyn::tree
