// A chain definition as a tree of numbers (ukdyn/symbolic/chain_tree.hpp): the same frames as
// build_chain (chain.cpp) composes symbolically, with every parameter substituted.
#include "ukdyn/symbolic/chain_tree.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <map>
#include <set>

#include "symbolic/ex_helpers.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;

// Thrown inside chain_tree() when the chain needs the symbolic derivation.
struct NotNumbers {
  std::string reason;
};

class TreeBuilder {
 public:
  explicit TreeBuilder(const ChainDef& c) : c_(c), values_(c.parameter_values()) {
    for (const auto& name : c.coordinates()) q_.push_back(coordinate_symbol(c.symbols(), name));
  }
  tree::Model build();

 private:
  [[nodiscard]] double number(const ex& e, const std::string& what) const;
  [[nodiscard]] Eigen::Vector3d vec(const Vec3Ex& v, const std::string& what) const;
  [[nodiscard]] Eigen::Matrix3d rpy(const Vec3Ex& v, const std::string& what) const;
  [[nodiscard]] Index coordinate(const std::string& name, const std::string& where) const;
  void inertial(const InertialDef& in, const std::string& where, tree::Link& link) const;
  void variable(const JointDef& j, const std::string& where, tree::Link& link) const;
  void quaternion_joint(const JointDef& j, const std::string& where, tree::Link& link) const;
  void base();
  void joint(const JointDef& j);

  const ChainDef& c_;
  const GiNaC::exmap values_;
  std::vector<GiNaC::symbol> q_;
  tree::Model m_;
  std::map<std::string, int> index_;  // link name → index (−1: the root)
  std::set<std::string> joint_names_;
  int last_ = -1;  // the previous joint's child: the default parent
};

double TreeBuilder::number(const ex& e, const std::string& what) const {
  const ex v = e.subs(values_).evalf();
  if (GiNaC::is_a<GiNaC::numeric>(v) && GiNaC::ex_to<GiNaC::numeric>(v).is_real()) {
    const double d = GiNaC::ex_to<GiNaC::numeric>(v).to_double();
    if (std::isfinite(d)) return d;
  }
  throw NotNumbers{what + " is not a number ('" + str(e) + "')"};
}

Eigen::Vector3d TreeBuilder::vec(const Vec3Ex& v, const std::string& what) const {
  return {number(v[0], what), number(v[1], what), number(v[2], what)};
}

// R = Rz(yaw) Ry(pitch) Rx(roll), as rpy_rotation (chain.cpp).
Eigen::Matrix3d TreeBuilder::rpy(const Vec3Ex& v, const std::string& what) const {
  const Eigen::Vector3d a = vec(v, what);
  return (Eigen::AngleAxisd(a.z(), Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(a.y(), Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(a.x(), Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

Index TreeBuilder::coordinate(const std::string& name, const std::string& where) const {
  const auto& cs = c_.coordinates();
  for (std::size_t k = 0; k < cs.size(); ++k) {
    if (cs[k] == name) return static_cast<Index>(k);
  }
  throw DefinitionError(where + ": '" + name + "' is not a coordinate of the chain");
}

// The link's mass, CoM and inertia turned into the link frame: I_link = R_rpy I R_rpyᵀ.
void TreeBuilder::inertial(const InertialDef& in, const std::string& where,
                           tree::Link& link) const {
  link.mass = number(in.mass, where + ": the mass");
  link.com = vec(in.com, where + ": the centre of mass");
  Eigen::Matrix3d I;
  for (int k = 0; k < 9; ++k)
    I(k / 3, k % 3) = number(in.inertia[static_cast<std::size_t>(k)], where + ": the inertia");
  const Eigen::Matrix3d R = rpy(in.rpy, where + ": the inertia rpy");
  link.inertia = R * I * R.transpose();
}

// θ = offset + Σ c_k q_k: a coordinate, or a value whose derivatives by the coordinates are
// numbers (affine).
void TreeBuilder::variable(const JointDef& j, const std::string& where, tree::Link& link) const {
  if (!j.value) {
    if (j.coordinate.empty()) throw DefinitionError(where + ": no coordinate and no value");
    link.terms.push_back({coordinate(j.coordinate, where), 1.0});
    return;
  }
  const ex v = j.value->subs(values_);
  GiNaC::exmap zero;
  for (std::size_t k = 0; k < q_.size(); ++k) {
    zero[q_[k]] = 0;
    const ex d = v.diff(q_[k]);
    if (d.is_zero()) continue;
    for (const auto& s : q_) {
      if (d.has(s))
        throw NotNumbers{where + ": its value '" + str(*j.value) +
                         "' is not affine in the coordinates"};
    }
    link.terms.push_back({static_cast<Index>(k), number(d, where + ": its value")});
  }
  link.offset = number(v.subs(zero), where + ": its value");
  if (link.terms.empty())
    throw NotNumbers{where + ": its value '" + str(*j.value) + "' is constant"};
}

// A floating joint's 7 (a ball joint's 4) coordinates, checked as build_chain checks them: its
// variables are these coordinates.
void TreeBuilder::quaternion_joint(const JointDef& j, const std::string& where,
                                   tree::Link& link) const {
  check_quaternion_joint(c_, j, where);
  for (const auto& c : j.coordinates) link.terms.push_back({coordinate(c, where), 1.0});
  link.type =
      j.type == JointDef::Type::floating ? tree::JointType::floating : tree::JointType::ball;
}

// x and y along the mount's axes, then the yaw about its z (build_chain's place_base).
void TreeBuilder::base() {
  const MobileBaseDef& B = c_.base;
  const std::string where = "mobile base";
  if (!B.yaw.empty()) (void)coordinate(B.yaw, where);
  const bool yaw = !B.yaw.empty();
  tree::Link x, y;
  x.name = B.link + "/x";
  x.joint = B.link + "/x";
  x.type = tree::JointType::prismatic;
  x.axis = Eigen::Vector3d::UnitX();
  x.terms.push_back({coordinate(B.x, where), 1.0});
  m_.links.push_back(x);
  y.name = yaw ? B.link + "/y" : B.link;
  y.joint = B.link + "/y";
  y.parent = 0;
  y.type = tree::JointType::prismatic;
  y.axis = Eigen::Vector3d::UnitY();
  y.terms.push_back({coordinate(B.y, where), 1.0});
  if (!yaw) inertial(B.inertial, where, y);
  m_.links.push_back(y);
  if (yaw) {
    tree::Link r;
    r.name = B.link;
    r.joint = B.link + "/yaw";
    r.parent = 1;
    r.type = tree::JointType::revolute;
    r.axis = Eigen::Vector3d::UnitZ();
    r.terms.push_back({coordinate(B.yaw, where), 1.0});
    inertial(B.inertial, where, r);
    m_.links.push_back(r);
  }
  last_ = static_cast<int>(m_.links.size()) - 1;
  index_[B.link] = last_;
}

void TreeBuilder::joint(const JointDef& j) {
  const std::string where = "joint '" + j.name + "'";
  // The same checks, in the same order, as build_chain's parent_frame.
  if (!joint_names_.insert(j.name).second)
    throw DefinitionError("duplicate joint '" + j.name + "'");
  if (j.link.empty()) throw DefinitionError(where + ": no child link");
  if (index_.count(j.link))
    throw DefinitionError(where + ": link '" + j.link + "' is defined twice");
  int parent = last_;
  if (!j.parent.empty()) {
    auto it = index_.find(j.parent);
    if (it == index_.end())
      throw DefinitionError(where + ": no parent link '" + j.parent + "' defined before it");
    parent = it->second;
  }
  tree::Link L;
  L.name = j.link;
  L.joint = j.name;
  L.parent = parent;
  L.origin_translation = vec(j.origin.xyz, where + ": the origin xyz");
  L.origin_rotation = rpy(j.origin.rpy, where + ": the origin rpy");
  if (j.type == JointDef::Type::fixed) {
    L.type = tree::JointType::fixed;
  } else if (j.type == JointDef::Type::floating || j.type == JointDef::Type::ball) {
    quaternion_joint(j, where, L);
  } else {
    L.type =
        j.type == JointDef::Type::revolute ? tree::JointType::revolute : tree::JointType::prismatic;
    const Eigen::Vector3d a = vec(j.axis, where + ": the axis");
    if (!(a.norm() > 0.0)) {  // the same message as build_chain's
      throw DefinitionError(where + ": the axis must be a nonzero constant vector, got [" +
                            str(j.axis[0]) + ", " + str(j.axis[1]) + ", " + str(j.axis[2]) + "]");
    }
    L.axis = a / a.norm();
    variable(j, where, L);
  }
  inertial(j.inertial, where, L);
  m_.links.push_back(std::move(L));
  last_ = static_cast<int>(m_.links.size()) - 1;
  index_[j.link] = last_;
}

tree::Model TreeBuilder::build() {
  if (!c_.extra_potential.is_zero()) throw NotNumbers{"the chain has an extra potential"};
  if (!c_.bodies.empty()) throw NotNumbers{"the chain has bodies besides its links"};
  m_.name = c_.name();
  m_.coordinates = c_.coordinates();
  m_.root_name = c_.base.enabled ? "" : c_.root_link;
  m_.root_rotation = rpy(c_.mount.rpy, "the mount rpy");
  m_.root_translation = vec(c_.mount.xyz, "the mount xyz");
  m_.gravity = vec(c_.gravity, "the gravity");
  index_[c_.root_link] = -1;
  if (c_.base.enabled) {
    index_.erase(c_.root_link);
    base();
  }
  for (const JointDef& j : c_.joints) joint(j);
  // The named points (build_chain's collect_links_and_points): `end` at the last joint's link
  // origin unless a point of that name is given.
  bool has_end = false;
  for (const PointDef& p : c_.points) {
    auto it = index_.find(p.link);
    if (it == index_.end())
      throw DefinitionError("point '" + p.name + "': no link '" + p.link + "'");
    m_.points.push_back({p.name, it->second, vec(p.xyz, "point '" + p.name + "'")});
    has_end = has_end || p.name == "end";
  }
  if (!has_end && !c_.joints.empty())
    m_.points.push_back({"end", index_.at(c_.joints.back().link), Eigen::Vector3d::Zero()});
  return std::move(m_);
}

}  // namespace

ChainTree chain_tree(const ChainDef& chain) {
  try {
    return {TreeBuilder(chain).build(), {}};
  } catch (const NotNumbers& e) {
    return {std::nullopt, e.reason};
  }
}

}  // namespace ukdyn::symbolic
