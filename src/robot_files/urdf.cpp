#include "ukdyn/robot_files/urdf.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <set>
#include <sstream>

#include "core/input_file.hpp"
#include "ukdyn/robot_files/visuals.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"

#ifdef UKDYN_HAVE_URDFDOM
#include <console_bridge/console.h>
#include <urdf_parser/urdf_parser.h>

#include <Eigen/Eigenvalues>
#include <mutex>
#endif

namespace ukdyn::symbolic {

#ifndef UKDYN_HAVE_URDFDOM

bool urdf_supported() { return false; }

void append_urdf(ChainDef&, const std::string& path, const std::map<std::string, GiNaC::ex>&) {
  throw DefinitionError(path + ": this ukdyn was built without urdfdom (install liburdfdom-dev)");
}

std::vector<LinkVisual> urdf_visuals(const std::string& path) {
  throw DefinitionError(path + ": this ukdyn was built without urdfdom (install liburdfdom-dev)");
}

#else

bool urdf_supported() { return true; }

namespace {

using GiNaC::ex;

ex angle(double a) {
  const double k = a / (std::numbers::pi / 4);
  const double kr = std::round(k);
  if (std::abs(a - kr * std::numbers::pi / 4) < 1e-12) {
    return GiNaC::numeric(static_cast<long>(kr), 4) * GiNaC::Pi;
  }
  return exact_number(a);
}

Vec3Ex vec(const urdf::Vector3& v) {
  return {exact_number(v.x), exact_number(v.y), exact_number(v.z)};
}

// Collects urdfdom's messages (it reports parse errors through console_bridge) instead of printing.
class Collect : public console_bridge::OutputHandler {
 public:
  void log(const std::string& text, console_bridge::LogLevel level, const char*, int) override {
    if (level < console_bridge::CONSOLE_BRIDGE_LOG_ERROR || messages.size() >= 2000) return;
    messages += (messages.empty() ? "" : "; ");
    for (char ch : text) {  // the text may quote a name from the XML: no control bytes
      const auto u = static_cast<unsigned char>(ch);
      messages += u >= 0x20 && u < 0x7f ? ch : '?';
    }
  }
  std::string messages;
};

urdf::ModelInterfaceSharedPtr parse_file(const std::string& xml, std::string& messages) {
  static std::mutex mutex;  // the output handler is global
  const std::lock_guard<std::mutex> lock(mutex);
  Collect collect;
  console_bridge::useOutputHandler(&collect);
  urdf::ModelInterfaceSharedPtr model;
  try {
    model = urdf::parseURDF(xml);
  } catch (...) {
    console_bridge::restorePreviousOutputHandler();
    throw;
  }
  console_bridge::restorePreviousOutputHandler();
  messages = collect.messages;
  return model;
}

// A name from the XML, for a message: printable ASCII only, at most 64 characters.
std::string shown(const std::string& s) {
  std::string out;
  for (std::size_t i = 0; i < s.size() && i < 64; ++i) {
    const auto u = static_cast<unsigned char>(s[i]);
    out += u >= 0x20 && u < 0x7f ? s[i] : '?';
  }
  return s.size() > 64 ? out + "..." : out;
}

// Fails unless every number of the pose is finite.
void check_pose(const urdf::Pose& p, const std::string& where) {
  const double v[7] = {p.position.x, p.position.y, p.position.z, p.rotation.x,
                       p.rotation.y, p.rotation.z, p.rotation.w};
  for (double x : v) {
    if (!std::isfinite(x)) throw DefinitionError(where + ": the <origin> has a non-finite number");
  }
}

OriginDef origin(const urdf::Pose& p) {
  double r = 0, pi = 0, y = 0;
  p.rotation.getRPY(r, pi, y);
  return {vec(p.position), {angle(r), angle(pi), angle(y)}};
}

// The text of the URDF file, read with the checks of every file ukdyn reads (a regular file of at
// most 16 MiB; a FIFO, folder or device named as what it is); urdfdom parses the text read.
std::string read_urdf(const std::string& path) {
  try {
    return detail::read_input_file(path, {"URDF file", 16 * detail::kMiB, path});
  } catch (const detail::InputFileError& e) {
    throw DefinitionError(e.what());
  }
}

// urdfdom's links own their children (shared_ptr): a cyclic file makes a reference cycle that
// would never be freed. Cuts every link's references on the way out, whatever the outcome.
struct Unlink {
  const urdf::ModelInterfaceSharedPtr& m;
  ~Unlink() {
    if (!m) return;
    for (auto& [name, link] : m->links_) {
      if (!link) continue;
      link->child_links.clear();
      link->child_joints.clear();
      link->parent_joint.reset();
    }
  }
};

// The parsed model's root link; refuses a file urdfdom could not read or reported errors in,
// and joint_values naming no joint of it.
urdf::LinkConstSharedPtr checked_root(const urdf::ModelInterfaceSharedPtr& model,
                                      const std::string& messages, const std::string& path,
                                      const std::map<std::string, GiNaC::ex>& joint_values) {
  if (!model) {
    throw DefinitionError(path + ": urdfdom could not read this URDF" +
                          (messages.empty() ? std::string(" (malformed XML?)") : ": " + messages));
  }
  // urdfdom reports some errors and carries on (a <mass value="heavy"/> drops the link's inertial
  // block, "inf" in an <inertia> likewise): any error it reported refuses the file.
  if (!messages.empty()) throw DefinitionError(path + ": urdfdom reported: " + messages);
  urdf::LinkConstSharedPtr root = model->getRoot();
  if (!root) throw DefinitionError(path + ": the URDF has no root link");
  for (const auto& [jn, j] : joint_values) {
    if (!model->getJoint(jn))
      throw DefinitionError(path + ": joint_values names no joint '" + jn + "'");
  }
  return root;
}

// The variables of the movable joints: the coordinates left for joints without an explicit
// value (free, from next on), and the value of every movable joint read so far (for mimic).
struct JointVariables {
  std::vector<std::string> free;
  std::size_t next = 0;
  std::map<std::string, ex> values;  // joint → its value
};

// Coordinates free for joints without an explicit value.
std::vector<std::string> free_coordinates(const ChainDef& chain,
                                          const std::map<std::string, GiNaC::ex>& joint_values) {
  std::set<std::string> taken;
  if (chain.base.enabled) {
    taken.insert(chain.base.x);
    taken.insert(chain.base.y);
    if (!chain.base.yaw.empty()) taken.insert(chain.base.yaw);
  }
  for (const auto& [jn, v] : joint_values) {
    if (GiNaC::is_a<GiNaC::symbol>(v)) taken.insert(GiNaC::ex_to<GiNaC::symbol>(v).get_name());
  }
  for (const auto& c : chain.floating_root) taken.insert(c);
  std::vector<std::string> free;
  for (const auto& c : chain.coordinates()) {
    if (!taken.count(c)) free.push_back(c);
  }
  return free;
}

// The root link: on the mobile base, on a floating joint, or the chain's root itself.
void attach_root(ChainDef& chain, const urdf::Link& root) {
  if (chain.base.enabled) {
    JointDef& j = chain.add_joint(root.name + "_mount", JointDef::Type::fixed, root.name);
    j.parent = chain.base.link;
    if (root.inertial) {
      j.inertial.mass = exact_number(root.inertial->mass);
    }
  } else if (!chain.floating_root.empty()) {
    // The root link on a floating joint from a fixed frame NAME_mount (docs/free-bodies.md).
    chain.root_link = root.name + "_mount";
    JointDef& j = chain.add_joint(root.name + "_floating", JointDef::Type::floating, root.name);
    j.parent = chain.root_link;
    j.coordinates = chain.floating_root;
  } else {
    chain.root_link = root.name;
  }
}

// Fails unless the link's <inertial> block (if any) is valid: finite, mass >= 0, the inertia about
// the CoM symmetric positive semi-definite (every message names the file and the link). Principal
// moments A, B, C that break the triangle inequality A + B >= C of a rigid body (relative
// tolerance 1e-6 of the largest, for rounded decimals) are noted, not refused: M stays positive
// semi-definite, and simplified models write such inertias on purpose (the paper's arm, whose
// turret has a moment about z only).
void check_inertial(const std::string& path, const urdf::Link& link,
                    std::vector<std::string>& notes) {
  if (!link.inertial) return;
  const urdf::Inertial& I = *link.inertial;
  const std::string where = path + ": link '" + shown(link.name) + "': <inertial>";
  if (!std::isfinite(I.mass) || I.mass < 0.0) {
    std::ostringstream os;
    os << where << ": <mass value> must be a finite number >= 0, got " << I.mass;
    throw DefinitionError(os.str());
  }
  for (double x : {I.ixx, I.ixy, I.ixz, I.iyy, I.iyz, I.izz}) {
    if (!std::isfinite(x)) throw DefinitionError(where + ": <inertia> has a non-finite entry");
  }
  if (I.ixx < 0.0 || I.iyy < 0.0 || I.izz < 0.0)
    throw DefinitionError(where + ": <inertia> has a negative diagonal entry (ixx, iyy, izz)");
  Eigen::Matrix3d M;
  M << I.ixx, I.ixy, I.ixz, I.ixy, I.iyy, I.iyz, I.ixz, I.iyz, I.izz;
  const Eigen::Vector3d e =
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(M, Eigen::EigenvaluesOnly).eigenvalues();
  const double scale = std::max(e(2), 0.0);  // ascending
  std::ostringstream os;
  os.precision(6);
  if (e(0) < -1e-12 * std::max(scale, 1.0)) {
    os << where << ": <inertia> is not positive semi-definite (principal moments " << e(0) << ", "
       << e(1) << ", " << e(2) << ")";
    throw DefinitionError(os.str());
  }
  if (e(0) + e(1) < e(2) * (1.0 - 1e-6)) {
    os << where << ": <inertia> breaks the triangle inequality of a rigid body: principal moments "
       << e(0) << " + " << e(1) << " < " << e(2)
       << " (ixx + iyy >= izz and its permutations); kept as written";
    notes.push_back(os.str());
  }
  check_pose(I.origin, where);
}

// A link's <inertial> block (checked by check_inertial). A link without one is massless, as the
// URDF specification makes <inertial> optional and as published robot files leave it out of
// base, flange and tool frames (ROS's ur_description, franka_description); a mass matrix this
// leaves singular is refused with the constraints (docs/free-bodies.md, "Singular mass
// matrices").
void read_inertial(const std::string& path, const urdf::Link& link, InertialDef& in,
                   std::vector<std::string>& notes) {
  if (!link.inertial) {
    in = InertialDef{};
    return;
  }
  check_inertial(path, link, notes);
  const urdf::Inertial& I = *link.inertial;
  in.mass = exact_number(I.mass);
  const OriginDef o = origin(I.origin);
  in.com = o.xyz;
  in.rpy = o.rpy;
  const ex xx = exact_number(I.ixx), xy = exact_number(I.ixy), xz = exact_number(I.ixz),
           yy = exact_number(I.iyy), yz = exact_number(I.iyz), zz = exact_number(I.izz);
  in.inertia = {xx, xy, xz, xy, yy, yz, xz, yz, zz};
}

// The joint's <limit>: lower and upper for revolute and prismatic joints (a continuous joint has
// no range), velocity and effort for all three. urdfdom reads a missing lower or upper as 0 and
// requires velocity and effort: a range with lower >= upper and a velocity or effort <= 0 are
// taken as absent (noted once per joint in `notes`).
void read_limits(const urdf::Joint& uj, const std::string& where, JointDef& j,
                 std::vector<std::string>& notes) {
  if (!uj.limits || j.type == JointDef::Type::fixed || j.type == JointDef::Type::floating) return;
  const urdf::JointLimits& l = *uj.limits;
  std::string ignored;
  if (uj.type == urdf::Joint::REVOLUTE || uj.type == urdf::Joint::PRISMATIC) {
    if (std::isfinite(l.lower) && std::isfinite(l.upper) && l.lower < l.upper) {
      j.limits.lower = l.lower;
      j.limits.upper = l.upper;
    } else {
      ignored += "the range (lower >= upper)";
    }
  }
  if (std::isfinite(l.velocity) && l.velocity > 0.0) {
    j.limits.velocity = l.velocity;
  } else {
    ignored += std::string(ignored.empty() ? "" : ", ") + "the velocity (<= 0)";
  }
  if (std::isfinite(l.effort) && l.effort > 0.0) {
    j.limits.effort = l.effort;
  } else {
    ignored += std::string(ignored.empty() ? "" : ", ") + "the effort (<= 0)";
  }
  if (!ignored.empty()) notes.push_back(where + ": <limit>: " + ignored + " taken as no limit");
}

// The number of <visual> and <collision> meshes of the file's links (ukdyn reads none of them).
std::size_t count_meshes(const urdf::ModelInterface& model) {
  std::size_t n = 0;
  for (const auto& [name, link] : model.links_) {
    if (!link) continue;
    for (const auto& v : link->visual_array)
      n += v && v->geometry && v->geometry->type == urdf::Geometry::MESH ? 1 : 0;
    for (const auto& c : link->collision_array)
      n += c && c->geometry && c->geometry->type == urdf::Geometry::MESH ? 1 : 0;
  }
  return n;
}

// Pushes the link's children on the stack (the first child on top); a child reached twice (a
// cycle, or a link that is the child of two joints: urdfdom keeps the last parent) is refused.
void push_children(const urdf::ModelInterface& model, const urdf::Link& link,
                   const std::string& path, std::set<std::string>& visited,
                   std::vector<urdf::LinkConstSharedPtr>& stack) {
  const auto& cj = link.child_joints;
  for (auto it = cj.rbegin(); it != cj.rend(); ++it) {
    urdf::LinkConstSharedPtr child = model.getLink((*it)->child_link_name);
    if (!child) continue;
    if (!visited.insert(child->name).second || child->parent_joint != *it) {
      throw DefinitionError(path + ": joint '" + shown((*it)->name) + "': link '" +
                            shown(child->name) +
                            "' is reached twice (a cycle, or a link with two parent joints): "
                            "a URDF must be a tree");
    }
    stack.push_back(child);
  }
}

JointDef::Type joint_type(const urdf::Joint& uj, const std::string& where) {
  switch (uj.type) {
    case urdf::Joint::REVOLUTE:
    case urdf::Joint::CONTINUOUS:
      return JointDef::Type::revolute;
    case urdf::Joint::PRISMATIC:
      return JointDef::Type::prismatic;
    case urdf::Joint::FIXED:
      return JointDef::Type::fixed;
    case urdf::Joint::FLOATING:  // position + unit quaternion, the next 7 free coordinates
      return JointDef::Type::floating;
    default:
      throw DefinitionError(
          where + ": type " +
          (uj.type == urdf::Joint::PLANAR ? std::string("planar") : std::string("unknown")) +
          " is not supported (revolute, continuous, prismatic, fixed, "
          "floating)");
  }
}

// A floating joint's 7 coordinates; a movable joint's value: given in joint_values, mimicking an
// earlier joint, or the next free coordinate.
void assign_joint_variables(const ChainDef& chain, JointDef& j, const urdf::Joint& uj,
                            const std::string& where,
                            const std::map<std::string, GiNaC::ex>& joint_values,
                            JointVariables& vars) {
  const std::vector<std::string>& free = vars.free;
  std::size_t& next = vars.next;
  if (j.type == JointDef::Type::floating) {
    if (next + 7 > free.size()) {
      throw DefinitionError(where +
                            ": a floating joint needs 7 coordinates (x, y, z, qw, qx, qy, "
                            "qz); the chain has " +
                            std::to_string(free.size() - next) + " left");
    }
    for (int k = 0; k < 7; ++k) j.coordinates.push_back(free[next++]);
  } else if (j.type != JointDef::Type::fixed) {
    j.axis = vec(uj.axis);
    if (auto v = joint_values.find(uj.name); v != joint_values.end()) {
      j.value = v->second;
    } else if (uj.mimic) {
      auto m = vars.values.find(uj.mimic->joint_name);
      if (m == vars.values.end()) {
        throw DefinitionError(where + ": mimics joint '" + uj.mimic->joint_name +
                              "', which is not a movable joint before it");
      }
      j.value = exact_number(uj.mimic->multiplier) * m->second + exact_number(uj.mimic->offset);
      j.mimic = uj.mimic->joint_name;
    } else {
      if (next >= free.size()) {
        throw DefinitionError(where + ": no coordinate left for it (the chain declares " +
                              std::to_string(chain.coordinates().size()) +
                              " coordinates; add one or give joint_values)");
      }
      j.value = coordinate_symbol(chain.symbols(), free[next++]);
    }
    vars.values[uj.name] = *j.value;
  }
}

// The joint from a non-root link's parent to it, with the link's inertia.
void append_link(ChainDef& chain, const urdf::Link& link, const std::string& root_name,
                 const std::string& path, const std::map<std::string, GiNaC::ex>& joint_values,
                 JointVariables& vars) {
  const urdf::Joint& uj = *link.parent_joint;
  const std::string where = path + ": joint '" + shown(uj.name) + "'";
  check_pose(uj.parent_to_joint_origin_transform, where);
  const JointDef::Type type = joint_type(uj, where);
  JointDef& j = chain.add_joint(uj.name, type, link.name);
  j.parent =
      uj.parent_link_name == root_name && chain.base.enabled ? root_name : uj.parent_link_name;
  j.origin = origin(uj.parent_to_joint_origin_transform);
  assign_joint_variables(chain, j, uj, where, joint_values, vars);
  read_limits(uj, where, j, chain.notes);
  read_inertial(path, link, j.inertial, chain.notes);
}

}  // namespace

void append_urdf(ChainDef& chain, const std::string& path,
                 const std::map<std::string, GiNaC::ex>& joint_values) {
  const std::string xml = read_urdf(path);
  std::string messages;
  const urdf::ModelInterfaceSharedPtr model = parse_file(xml, messages);
  const Unlink unlink{model};  // whatever the outcome
  const urdf::LinkConstSharedPtr root = checked_root(model, messages, path, joint_values);
  JointVariables vars{free_coordinates(chain, joint_values), 0, {}};
  std::vector<std::string> root_notes;      // read_inertial below notes it again if it is used
  check_inertial(path, *root, root_notes);  // named even where unused (a root fixed in the world)
  if (!chain.base.enabled && chain.floating_root.empty())
    chain.notes.insert(chain.notes.end(), root_notes.begin(), root_notes.end());
  attach_root(chain, *root);
  if ((chain.base.enabled || !chain.floating_root.empty()) && root->inertial)
    read_inertial(path, *root, chain.joints.back().inertial, chain.notes);

  // Depth-first from the root: parents are defined before their children (push_children refuses
  // a link reached twice).
  std::set<std::string> visited{root->name};
  std::vector<urdf::LinkConstSharedPtr> stack{root};
  while (!stack.empty()) {
    const urdf::LinkConstSharedPtr link = stack.back();
    stack.pop_back();
    push_children(*model, *link, path, visited, stack);
    if (link == root) continue;
    append_link(chain, *link, root->name, path, joint_values, vars);
  }
  if (const std::size_t meshes = count_meshes(*model); meshes > 0) {
    chain.notes.push_back(
        path + ": " + std::to_string(meshes) + (meshes == 1 ? " mesh" : " meshes") +
        " ignored: ukdyn reads kinematics and inertia only; visuals are not drawn");
  }
}

namespace {

// One <visual>'s geometry as a LinkVisual (sizes as extents; docs/replay.md).
LinkVisual link_visual(const std::string& link, const urdf::Visual& v) {
  LinkVisual lv;
  lv.link = link;
  const urdf::Pose& o = v.origin;
  lv.xyz = {o.position.x, o.position.y, o.position.z};
  lv.quat = {o.rotation.w, o.rotation.x, o.rotation.y, o.rotation.z};
  const urdf::GeometrySharedPtr& g = v.geometry;
  if (const auto box = std::dynamic_pointer_cast<urdf::Box>(g)) {
    lv.shape = "box";
    lv.size = {box->dim.x, box->dim.y, box->dim.z};
  } else if (const auto cyl = std::dynamic_pointer_cast<urdf::Cylinder>(g)) {
    lv.shape = "cylinder";  // along the visual frame's z (URDF)
    lv.size = {2 * cyl->radius, 2 * cyl->radius, cyl->length};
  } else if (const auto sph = std::dynamic_pointer_cast<urdf::Sphere>(g)) {
    lv.shape = "sphere";
    lv.size = {2 * sph->radius, 2 * sph->radius, 2 * sph->radius};
  } else if (const auto mesh = std::dynamic_pointer_cast<urdf::Mesh>(g)) {
    lv.shape = "mesh";
    lv.detail = shown(mesh->filename);
  } else {
    lv.shape = "unknown";
  }
  return lv;
}

}  // namespace

std::vector<LinkVisual> urdf_visuals(const std::string& path) {
  const std::string xml = read_urdf(path);
  std::string messages;
  const urdf::ModelInterfaceSharedPtr model = parse_file(xml, messages);
  const Unlink unlink{model};  // whatever the outcome
  if (!model) throw DefinitionError(path + ": urdfdom could not read it: " + messages);
  std::vector<LinkVisual> out;
  for (const auto& [name, link] : model->links_) {
    if (!link) continue;
    for (const auto& v : link->visual_array) {
      if (v && v->geometry) out.push_back(link_visual(name, *v));
    }
  }
  return out;
}

#endif

}  // namespace ukdyn::symbolic
