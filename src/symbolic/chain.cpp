#include "ukdyn/symbolic/chain.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <set>
#include <sstream>

#include "symbolic/ex_helpers.hpp"
#include "symbolic/mat3.hpp"
#include "ukdyn/symbolic/canonical.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/symbolic/free_body.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;

Mat3Ex identity3() { return {1, 0, 0, 0, 1, 0, 0, 0, 1}; }

// The product of two rotations along the chain (mat3.hpp's exact mul) with its numbers bounded:
// every non-integer rational longer than 256 bits rounded to the exact rational of its double
// (round_long_rationals, canonical.hpp). Composed exactly, the rotations by constant angles of a
// chain (rpy of fixed joints: exact rationals of cos and sin, see axis_rotation) multiply out into
// numbers whose length grows with every joint; the rounding is exact-number arithmetic, so the
// result is the same in every process.
Mat3Ex compose(const Mat3Ex& a, const Mat3Ex& b) {
  Mat3Ex r = mul(a, b);
  for (ex& e : r) e = round_long_rationals(e);  // bounded numbers (canonical.hpp)
  return r;
}

Vec3Ex add(const Vec3Ex& a, const Vec3Ex& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }

Vec3Ex scale(const Vec3Ex& a, const ex& s) { return {a[0] * s, a[1] * s, a[2] * s}; }

bool all_zero(const Vec3Ex& v) { return v[0].is_zero() && v[1].is_zero() && v[2].is_zero(); }

Vec3Ex unit(const Vec3Ex& a, const std::string& where, const GiNaC::exmap& values) {
  const ex n2 = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).expand();
  const ex v = n2.subs(values).evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !(GiNaC::ex_to<GiNaC::numeric>(v).to_double() > 0.0)) {
    throw DefinitionError(where + ": the axis must be a nonzero constant vector, got [" +
                          str(a[0]) + ", " + str(a[1]) + ", " + str(a[2]) + "]");
  }
  if (n2.is_equal(1)) return a;
  const ex n = GiNaC::sqrt(n2);
  return {a[0] / n, a[1] / n, a[2] / n};
}

}  // namespace

Mat3Ex axis_rotation(const Vec3Ex& a, const ex& q) {
  // R = cos q · 1 + (1 − cos q) a aᵀ + sin q [a]×
  // A constant angle that is not a multiple of pi/4 (rpy: [0.3, 0.2, 0.1]) gives cos(3/10), which
  // GiNaC keeps exact: a chain of such rotations multiplied out into polynomials of growing degree
  // in these constants (15 fixed joints: minutes). Their cosines and sines are taken as the exact
  // rationals of their doubles instead. Not as GiNaC floats: float arithmetic inside expressions
  // follows GiNaC's operand order, which differs between processes (canonical.hpp), and made the
  // derived M of the welded N-robot scenarios differ in the last bits from run to run.
  ex c = GiNaC::cos(q), s = GiNaC::sin(q);
  // An angle within 1e-12 of a multiple of pi/4 (a quarter turn written as 1.5707963267948966,
  // an MJCF quaternion's angle) is taken as that multiple, whose cosine and sine GiNaC keeps
  // exact and short, as urdf.cpp does: the exact rationals of cos(1.5707963267948966) = 6.1e-17
  // would carry ~160-bit numbers through every product of the chain.
  if (GiNaC::is_a<GiNaC::numeric>(q) && GiNaC::ex_to<GiNaC::numeric>(q).is_real()) {
    const double v = GiNaC::ex_to<GiNaC::numeric>(q).to_double();
    const double k = std::round(v / (std::numbers::pi / 4));
    if (std::abs(v - k * std::numbers::pi / 4) < 1e-12 && std::abs(k) < 1e6) {
      const ex turn = GiNaC::numeric(static_cast<long>(k), 4) * GiNaC::Pi;
      c = GiNaC::cos(turn);
      s = GiNaC::sin(turn);
    } else {
      c = exact_rational(std::cos(v));
      s = exact_rational(std::sin(v));
    }
  }
  const Mat3Ex K{0, -a[2], a[1], a[2], 0, -a[0], -a[1], a[0], 0};
  Mat3Ex R;
  for (std::size_t i = 0; i < 3; ++i) {
    for (std::size_t j = 0; j < 3; ++j) {
      R[3 * i + j] = (i == j ? c : ex(0)) + (1 - c) * a[i] * a[j] + s * K[3 * i + j];
      R[3 * i + j] = R[3 * i + j].expand();
    }
  }
  return R;
}

Mat3Ex rpy_rotation(const Vec3Ex& rpy) {
  Mat3Ex R = identity3();
  // Rz(yaw) Ry(pitch) Rx(roll); skip zero angles to keep the expressions small.
  if (!rpy[2].is_zero()) R = compose(R, axis_rotation({0, 0, 1}, rpy[2]));
  if (!rpy[1].is_zero()) R = compose(R, axis_rotation({0, 1, 0}, rpy[1]));
  if (!rpy[0].is_zero()) R = compose(R, axis_rotation({1, 0, 0}, rpy[0]));
  return R;
}

JointDef& ChainDef::add_joint(std::string joint_name, JointDef::Type type, std::string link) {
  joints.emplace_back();
  joints.back().name = std::move(joint_name);
  joints.back().type = type;
  joints.back().link = std::move(link);
  return joints.back();
}

void ChainDef::add_point(std::string point_name, std::string link, Vec3Ex xyz) {
  points.push_back({std::move(point_name), std::move(link), std::move(xyz)});
}

namespace {

// A number, if e is one (finite, real) once evaluated.
std::optional<double> number_of(const GiNaC::ex& e) {
  const GiNaC::ex v = e.evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real())
    return std::nullopt;
  const double d = GiNaC::ex_to<GiNaC::numeric>(v).to_double();
  return std::isfinite(d) ? std::optional<double>(d) : std::nullopt;
}

// θ = c · q_k + offset: (k, c, offset) if the joint's value has that form, else nullopt.
struct AffineInOne {
  std::size_t k = 0;
  double c = 1.0, offset = 0.0;
};
std::optional<AffineInOne> affine_in_one(const ChainDef& chain, const JointDef& j,
                                         const GiNaC::exmap& values) {
  const auto& cs = chain.coordinates();
  if (!j.value) {
    for (std::size_t k = 0; k < cs.size(); ++k)
      if (cs[k] == j.coordinate) return AffineInOne{k, 1.0, 0.0};
    return std::nullopt;
  }
  const GiNaC::ex v = j.value->subs(values);
  std::optional<AffineInOne> found;
  GiNaC::exmap zero;
  for (std::size_t k = 0; k < cs.size(); ++k) {
    const GiNaC::symbol q = coordinate_symbol(chain.symbols(), cs[k]);
    zero[q] = 0;
    if (!v.has(q)) continue;
    const auto c = number_of(v.diff(q));
    if (found || !c || *c == 0.0) return std::nullopt;  // two coordinates, or not affine
    found = AffineInOne{k, *c, 0.0};
  }
  if (!found) return std::nullopt;
  const auto off = number_of(v.subs(zero));
  if (!off) return std::nullopt;
  found->offset = *off;
  return found;
}

}  // namespace

std::vector<CoordinateLimits> ChainDef::coordinate_limits() const {
  std::vector<CoordinateLimits> out(coordinates().size());
  const GiNaC::exmap values = parameter_values();
  for (const JointDef& j : joints) {
    if (!j.limits.any() || !j.mimic.empty() || j.type == JointDef::Type::fixed ||
        j.type == JointDef::Type::floating || j.type == JointDef::Type::ball)
      continue;
    const auto a = affine_in_one(*this, j, values);
    if (!a) continue;
    double lo = (j.limits.lower - a->offset) / a->c, hi = (j.limits.upper - a->offset) / a->c;
    if (a->c < 0.0) std::swap(lo, hi);
    CoordinateLimits& L = out[a->k];
    L.lower = std::max(L.lower, lo);
    L.upper = std::min(L.upper, hi);
    L.velocity = std::min(L.velocity, j.limits.velocity / std::abs(a->c));
    L.effort = std::min(L.effort, j.limits.effort * std::abs(a->c));
  }
  return out;
}

Vec3Ex ChainModel::world_point(const std::string& name) const {
  auto it = points.find(name);
  if (it == points.end()) {
    std::string known;
    for (const auto& [k, v] : points) known += (known.empty() ? "" : ", ") + k;
    throw DefinitionError("subsystem '" + def.name() + "' has no point '" + name +
                          "' (known: " + known + ")");
  }
  const GiNaC::exmap values = def.parameter_values();
  return {it->second[0].subs(values), it->second[1].subs(values), it->second[2].subs(values)};
}

namespace {

// A link frame while the chain is built.
struct Pose {
  Vec3Ex p;
  Mat3Ex R;
  Vec3Ex w;  // angular velocity in the world
  // R = Rpre · Rot(axis, angle) when the last rotation was about `axis` (has_axis): a child joint
  // about the same axis adds its angle, so parallel joints give cos(q1 + q2), and the paper's
  // absolute angles (values theta2 − theta1) give back Ry(−theta2) exactly as written by hand.
  Mat3Ex Rpre;
  Vec3Ex axis{0, 0, 0};
  ex angle = 0;
  bool has_axis = false;
  // Downstream of a floating joint: the angular velocity in the frame's own axes (wb), composed
  // joint by joint with orthonormal steps, so that a body fixed to the floating link gets
  // exactly the free body's ω_body = 2 E(q) q̇ (free_body.hpp); w is then unused.
  bool floating = false;
  Vec3Ex wb{0, 0, 0};
};

// The joint frame: the parent link frame P moved by the joint's fixed origin.
Pose origin_frame(const Pose& P, const OriginDef& origin, const Deadline& deadline,
                  const std::string& where) {
  Pose jf = P;
  jf.p = add(P.p, mul(P.R, origin.xyz));
  if (P.floating && !all_zero(origin.rpy)) {
    jf.wb = mul_transposed(rpy_rotation(origin.rpy), P.wb);
    for (auto& e : jf.wb) e = expand_checked(e, deadline, where);
  }
  if (!all_zero(origin.rpy)) {
    // Expanded at every joint: left as products, a chain of a dozen fixed joints with rotated
    // origins grew 3-fold per joint (each entry refers to three of its parent's) and expanding
    // the positions below took minutes.
    jf.R = compose(P.R, rpy_rotation(origin.rpy));
    for (auto& e : jf.R) e = expand_checked(e, deadline, where);
    jf.has_axis = false;
  }
  return jf;
}

// One build_chain call: the chain's coordinate symbols, the link frames built so far (a parent
// before its children) and the model being filled.
class ChainBuilder {
 public:
  ChainBuilder(const ChainDef& chain, const Deadline& deadline);
  // The root (or the mobile base), then every joint in order, then the links and named points.
  ChainModel build();

 private:
  [[nodiscard]] bool has_coord(const std::string& c) const;
  [[nodiscard]] ex rate(const ex& v) const;
  void check_value(const ex& v, const std::string& where) const;
  void add_body(const std::string& name, const Pose& f, const InertialDef& in);
  void place_base(const Pose& root, const Mat3Ex& Rm);
  [[nodiscard]] const Pose& parent_frame(const JointDef& j, const std::string& where);
  void apply_quaternion_joint(const JointDef& j, const std::string& where, Pose& jf);
  [[nodiscard]] ex joint_value(const JointDef& j, const std::string& where) const;
  void apply_axis_joint(const JointDef& j, const std::string& where, Pose& jf) const;
  void place_joint(const JointDef& j);
  void collect_links_and_points();

  const ChainDef& chain_;
  const Deadline& deadline_;  // bounded work (docs/definitions.md, Limits)
  ChainModel m_;
  const GiNaC::exmap values_;
  const std::vector<std::string>& coords_;
  std::vector<GiNaC::symbol> q_, qd_;
  std::map<std::string, Pose> frames_;
  std::string last_;  // the previous joint's child link: the default parent
  std::set<std::string> joint_names_;
};

ChainBuilder::ChainBuilder(const ChainDef& chain, const Deadline& deadline)
    : chain_(chain),
      deadline_(deadline),
      m_{static_cast<const SubsystemDef&>(chain), {}, {}, {}},
      values_(chain.parameter_values()),
      coords_(chain.coordinates()) {
  for (const auto& c : coords_) {
    q_.push_back(coordinate_symbol(chain.symbols(), c));
    qd_.push_back(velocity_symbol(chain.symbols(), c));
  }
}

bool ChainBuilder::has_coord(const std::string& c) const {
  return std::find(coords_.begin(), coords_.end(), c) != coords_.end();
}

ex ChainBuilder::rate(const ex& v) const {
  ex r = 0;
  for (std::size_t k = 0; k < q_.size(); ++k) r += v.diff(q_[k]) * qd_[k];
  return r;
}

// Only the chain's coordinates and parameters may appear in a joint value.
void ChainBuilder::check_value(const ex& v, const std::string& where) const {
  GiNaC::exmap zero = values_;
  for (const auto& s : q_) zero[s] = 0;
  const ex z = v.subs(zero).evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(z)) {
    throw DefinitionError(where + ": the joint value '" + str(v) +
                          "' may use only the chain's coordinates and parameters");
  }
}

void ChainBuilder::add_body(const std::string& name, const Pose& f, const InertialDef& in) {
  bool has_inertia = false;
  for (const ex& e : in.inertia) has_inertia = has_inertia || !e.is_zero();
  if (in.mass.is_zero() && !has_inertia) return;
  BodyDef& b = m_.def.add_body(name);
  b.mass = in.mass;
  b.com = add(f.p, mul(f.R, in.com));
  if (has_inertia) {
    const Mat3Ex Rb = all_zero(in.rpy) ? f.R : compose(f.R, rpy_rotation(in.rpy));
    b.inertia_kind = BodyDef::InertiaKind::tensor;
    b.inertia_tensor = in.inertia;
    b.inertia_frame = symbolic::Frame::body;
    b.rotation = Rb;
    Vec3Ex wb = f.floating ? (all_zero(in.rpy) ? f.wb : mul_transposed(rpy_rotation(in.rpy), f.wb))
                           : mul_transposed(Rb, f.w);
    for (auto& e : wb) e = simplify_trig(e, deadline_, "body '" + name + "'");
    b.angular_velocity = wb;
  }
}

// The mobile base: x, y along the mount's axes, an optional yaw about its z.
void ChainBuilder::place_base(const Pose& root, const Mat3Ex& Rm) {
  const auto& B = chain_.base;
  if (!has_coord(B.x) || !has_coord(B.y)) {
    throw DefinitionError("mobile base: x and y must be coordinates of the chain (got '" + B.x +
                          "', '" + B.y + "')");
  }
  Pose f = root;
  f.p = add(f.p, mul(Rm, Vec3Ex{coordinate_symbol(chain_.symbols(), B.x),
                                coordinate_symbol(chain_.symbols(), B.y), 0}));
  if (!B.yaw.empty()) {
    if (!has_coord(B.yaw))
      throw DefinitionError("mobile base: yaw '" + B.yaw + "' is not a coordinate of the chain");
    f.R = compose(Rm, axis_rotation({0, 0, 1}, coordinate_symbol(chain_.symbols(), B.yaw)));
    f.Rpre = Rm;
    f.axis = {0, 0, 1};
    f.angle = coordinate_symbol(chain_.symbols(), B.yaw);
    f.has_axis = true;
    f.w = scale(Vec3Ex{Rm[2], Rm[5], Rm[8]}, velocity_symbol(chain_.symbols(), B.yaw));
  }
  frames_[B.link] = f;
  last_ = B.link;
  add_body(B.link, f, B.inertial);
}

// The joint's names checked (unique joint, a new child link) and its parent link's frame.
const Pose& ChainBuilder::parent_frame(const JointDef& j, const std::string& where) {
  if (!joint_names_.insert(j.name).second)
    throw DefinitionError("duplicate joint '" + j.name + "'");
  if (j.link.empty()) throw DefinitionError(where + ": no child link");
  if (frames_.count(j.link))
    throw DefinitionError(where + ": link '" + j.link + "' is defined twice");
  const std::string parent = j.parent.empty() ? last_ : j.parent;
  auto pit = frames_.find(parent);
  if (pit == frames_.end())
    throw DefinitionError(where + ": no parent link '" + parent + "' defined before it");
  return pit->second;
}

void ChainBuilder::apply_quaternion_joint(const JointDef& j, const std::string& where, Pose& jf) {
  // Position + unit quaternion (docs/free-bodies.md, "Floating joints"): p = p_joint +
  // R_joint (x, y, z) (floating only), R = R_joint R(q), ω_body = R(q)ᵀ ω_joint + 2 E(q) q̇,
  // the free body's rate (free_body.hpp) plus the joint frame's own angular velocity.
  const bool floating = j.type == JointDef::Type::floating;
  const std::size_t nc = floating ? 7 : 4;
  check_quaternion_joint(chain_, j, where);
  // The joint frame's angular velocity in its own axes (jf.R is orthonormal off a floating
  // part: products of rotations about axes).
  Vec3Ex wj = jf.wb;
  if (!jf.floating) {
    wj = mul_transposed(jf.R, jf.w);
    for (auto& e : wj) e = simplify_trig(e, deadline_, where);
  }
  std::vector<ex> c(nc), d(nc);
  for (std::size_t k = 0; k < nc; ++k) {
    c[k] = coordinate_symbol(chain_.symbols(), j.coordinates[k]);
    d[k] = velocity_symbol(chain_.symbols(), j.coordinates[k]);
  }
  const std::size_t o = floating ? 3 : 0;
  if (floating) jf.p = add(jf.p, mul(jf.R, Vec3Ex{c[0], c[1], c[2]}));
  const Mat3Ex Rq = quaternion_rotation(c[o], c[o + 1], c[o + 2], c[o + 3]);
  jf.R = compose(jf.R, Rq);
  for (auto& e : jf.R) e = expand_checked(e, deadline_, where);
  jf.wb = add(mul_transposed(Rq, wj), quaternion_body_rate(c[o], c[o + 1], c[o + 2], c[o + 3], d[o],
                                                           d[o + 1], d[o + 2], d[o + 3]));
  for (auto& e : jf.wb) e = expand_checked(e, deadline_, where);
  jf.floating = true;
  jf.has_axis = false;
  m_.quaternions.emplace_back(
      j.name,
      std::vector<std::string>(j.coordinates.begin() + static_cast<long>(o), j.coordinates.end()));
}

// A revolute or prismatic joint's variable: its value (checked) or its coordinate.
ex ChainBuilder::joint_value(const JointDef& j, const std::string& where) const {
  if (j.value) {
    const ex v = *j.value;
    check_value(v, where);
    return v;
  }
  if (j.coordinate.empty()) throw DefinitionError(where + ": no coordinate and no value");
  if (!has_coord(j.coordinate)) {
    throw DefinitionError(where + ": '" + j.coordinate + "' is not a coordinate of the chain");
  }
  return coordinate_symbol(chain_.symbols(), j.coordinate);
}

void ChainBuilder::apply_axis_joint(const JointDef& j, const std::string& where, Pose& jf) const {
  const ex v = joint_value(j, where);
  const Vec3Ex a = unit(j.axis, where, values_);
  if (j.type == JointDef::Type::revolute && jf.floating) {
    // Body-frame composition: ω_child = Rot(a, v)ᵀ ω_joint + a v̇.
    jf.wb = add(mul_transposed(axis_rotation(a, v), jf.wb), scale(a, rate(v)));
    for (auto& e : jf.wb) e = expand_checked(e, deadline_, where);
  }
  if (j.type == JointDef::Type::revolute) {
    if (!jf.floating) jf.w = add(jf.w, scale(mul(jf.R, a), rate(v)));
    const bool same_axis = jf.has_axis && jf.axis[0].is_equal(a[0]) && jf.axis[1].is_equal(a[1]) &&
                           jf.axis[2].is_equal(a[2]);
    if (same_axis) {
      jf.angle = (jf.angle + v).expand();
    } else {
      jf.Rpre = jf.R;
      jf.axis = a;
      jf.angle = v;
      jf.has_axis = true;
    }
    jf.R = compose(jf.Rpre, axis_rotation(a, jf.angle));
    for (auto& e : jf.R) e = expand_checked(e, deadline_, where);
  } else {
    jf.p = add(jf.p, mul(jf.R, scale(a, v)));
  }
}

void ChainBuilder::place_joint(const JointDef& j) {
  const std::string where = "joint '" + j.name + "'";
  deadline_.check(where);
  Pose jf = origin_frame(parent_frame(j, where), j.origin, deadline_, where);
  if (j.type == JointDef::Type::floating || j.type == JointDef::Type::ball) {
    apply_quaternion_joint(j, where, jf);
  } else if (j.type != JointDef::Type::fixed) {
    apply_axis_joint(j, where, jf);
  }
  for (auto& e : jf.p) e = expand_checked(e, deadline_, where);
  for (std::size_t k = 0; k < 3; ++k) check_expression_size(jf.p[k], where + ": its position");
  for (std::size_t k = 0; k < 9; ++k) check_expression_size(jf.R[k], where + ": its rotation");
  frames_[j.link] = jf;
  last_ = j.link;
  add_body(j.link, jf, j.inertial);
}

void ChainBuilder::collect_links_and_points() {
  for (const auto& [name, f] : frames_) {
    m_.links[name] = {f.p, f.R};
    m_.points[name] = f.p;
  }
  if (!chain_.joints.empty()) m_.points["end"] = frames_[chain_.joints.back().link].p;
  for (const PointDef& p : chain_.points) {
    auto it = frames_.find(p.link);
    if (it == frames_.end())
      throw DefinitionError("point '" + p.name + "': no link '" + p.link + "'");
    Vec3Ex w = add(it->second.p, mul(it->second.R, p.xyz));
    for (auto& e : w) e = expand_checked(e, deadline_, "point '" + p.name + "'");
    m_.points[p.name] = w;
  }
}

ChainModel ChainBuilder::build() {
  const Mat3Ex Rm = rpy_rotation(chain_.mount.rpy);
  Pose root;
  root.p = chain_.mount.xyz;
  root.R = Rm;
  root.w = {0, 0, 0};
  last_ = chain_.root_link;
  if (chain_.base.enabled) {
    place_base(root, Rm);
  } else {
    frames_[chain_.root_link] = root;
  }
  for (const JointDef& j : chain_.joints) place_joint(j);
  collect_links_and_points();
  return std::move(m_);
}

}  // namespace

void check_quaternion_joint(const ChainDef& chain, const JointDef& j, const std::string& where) {
  const bool floating = j.type == JointDef::Type::floating;
  const std::size_t nc = floating ? 7 : 4;
  const std::string kind = floating ? "a floating" : "a ball";
  if (j.coordinates.size() != nc) {
    throw DefinitionError(where + ": " + kind + " joint has " + std::to_string(nc) +
                          " coordinates (" +
                          (floating ? "x, y, z, qw, qx, qy, qz" : "qw, qx, qy, qz") + "), got " +
                          std::to_string(j.coordinates.size()));
  }
  const auto& cs = chain.coordinates();
  for (const auto& c : j.coordinates) {
    if (std::find(cs.begin(), cs.end(), c) == cs.end())
      throw DefinitionError(where + ": '" + c + "' is not a coordinate of the chain");
  }
  if (j.value || !j.coordinate.empty())
    throw DefinitionError(where + ": " + kind +
                          " joint takes coordinates, not a coordinate or value");
}

ChainModel build_chain(const ChainDef& chain) { return build_chain(chain, Deadline()); }

ChainModel build_chain(const ChainDef& chain, const Deadline& deadline) {
  return ChainBuilder(chain, deadline).build();
}

}  // namespace ukdyn::symbolic
