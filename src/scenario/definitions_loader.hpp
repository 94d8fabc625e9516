// Internal to ukdyn::io: loading subsystems (type: definitions, serial_chain) and constraints
// (type: expression, nonholonomic, points_coincide, point_trajectory, angle_relation) written as
// definitions; see docs/definitions.md. Every error names file:line:col and the key; errors inside
// an expression point at the column of the offending character.
#pragma once

#include <array>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "scenario/yaml_loader.hpp"
#include "ukdyn/model/constraint.hpp"
#include "ukdyn/model/subsystem.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"
#include "ukdyn/symbolic/numeric_frame_constraint.hpp"

namespace ukdyn {
struct LoadedDefinitions;  // below: the io_detail::DefinitionContext (opaque in Scenario)
}  // namespace ukdyn

namespace ukdyn::io_detail {

/// One copy of a subsystem written once (`instances:`, docs/scenario-format.md): its coordinates
/// are the template's with a prefix; the template's own names (`local`) stay usable inside its
/// expressions (as aliases of the prefixed coordinates and velocities); `parameters` replace the
/// template's values of the same name; `mount` (serial_chain) replaces the template's mount.
struct InstanceSpec {
  std::vector<std::string> local;          ///< the template's coordinate names
  std::map<std::string, Node> parameters;  ///< name → the instance's value node
  Node mount;                              ///< undefined: the template's
};

/// What later constraints and the replay page need of the subsystems loaded (definitions_loader.cpp);
/// the opaque ukdyn::LoadedDefinitions of Scenario::definitions.
using DefinitionContext = ::ukdyn::LoadedDefinitions;

/// The context's pool of compiled tapes (null without a context): the instances of one robot share
/// their tapes through it.
symbolic::TapePool* tape_pool(DefinitionContext* context);

/// A subsystem node with type: definitions. `gravity` is the scenario's g (default gravity vector
/// [0, 0, −g]).
/// ... its bodies' CoMs are recorded in `context` if given (for the replay page).
std::shared_ptr<const Subsystem> load_definitions_subsystem(
    const Loader& L, const Node& s, const std::string& name,
    const std::vector<std::string>& coordinates, double gravity,
    const InstanceSpec* instance = nullptr, DefinitionContext* context = nullptr);

/// A subsystem node with type: free_body (docs/free-bodies.md): 7 coordinates (x, y, z, qw, qx,
/// qy, qz), mass, inertia (body frame). Its unit-norm row is added by the scenario loader. Its body
/// is registered as the frame NAME.NAME in `context` (frame constraints).
std::shared_ptr<const Subsystem> load_free_body_subsystem(
    const Loader& L, const Node& s, const std::string& name,
    const std::vector<std::string>& coordinates, double gravity,
    DefinitionContext* context = nullptr);

/// Records a definition's bodies in `context` (if given): its frames for frame constraints and
/// its bodies' CoMs for the replay page, as load_definitions_subsystem does (wheeled platforms);
/// `base` the coordinates drawn with the platform displacements (m), not among the angles.
void record_definition_bodies(DefinitionContext* context, const std::string& name,
                              const symbolic::SubsystemDef& def,
                              const std::vector<std::string>& base = {});

/// A constraint node with type: expression (holonomic) or nonholonomic. `system_coordinates` are
/// all coordinates in order. Its tapes are kept in `pool` (if given): constraints that differ in
/// their numbers only (the grasps of instances) share one (DerivedConstraint).
std::shared_ptr<const Constraint> load_definitions_constraint(
    const Loader& L, const Node& c, const std::string& name, bool holonomic,
    const std::vector<std::string>& system_coordinates, symbolic::TapePool* pool = nullptr);

/// What later constraints may refer to: the named points of serial chains, by subsystem name.
std::shared_ptr<DefinitionContext> make_definition_context();
/// LoadOptions::symbolic_chains: serial chains with `dynamics: auto` derived symbolically.
void set_symbolic_chains(DefinitionContext& context, bool symbolic);
/// The frames of the chains and definition bodies loaded so far (docs/frame-constraints.md).
/// The frame SUBSYSTEM.FRAME (or world) of the chains and definition bodies loaded so far
/// (docs/frame-constraints.md); a chain on the tree algorithms gets its symbolic kinematics built
/// first (require_chain). Throws DefinitionError naming the frame, or what build_chain throws.
const symbolic::FramePose& find_frame(DefinitionContext& context, const std::string& name);
/// Builds the symbolic kinematics (link poses, points, frames: symbolic::build_chain) of serial
/// chain `name` if it runs on the tree algorithms and they have not been built yet: only a
/// constraint, force or frame on its points needs them (a 30-link chain's expanded poses would take
/// minutes). Nothing for other names. Throws what build_chain throws.
void require_chain(DefinitionContext& context, const std::string& name);
/// The numeric end (symbolic/numeric_frame_constraint.hpp) of frame SUBSYSTEM.FRAME moved by
/// `offset` (its parameters given by `values`) when SUBSYSTEM is a serial chain on the tree
/// algorithms and the offset is numbers (docs/tree-algorithms.md); nullopt otherwise (the frame
/// is then found by find_frame). FRAME is a link of the chain or one of its named points (with
/// its link's axes). Throws DefinitionError naming the known frames if there is no such frame.
std::optional<symbolic::NumericFrameEnd> tree_frame_end(
    const DefinitionContext& context, const std::string& name, const symbolic::OriginDef& offset,
    const GiNaC::exmap& values, const std::vector<std::string>& system_coordinates);
/// The constraints between the links of serial_chain subsystem `name` (its MJCF file's weld and
/// connect equalities; empty if none, or no context).
std::vector<symbolic::LinkConstraintDef> chain_link_constraints(const DefinitionContext* context,
                                                                const std::string& name);
/// The chain model of serial_chain subsystem `name` (null if none, or no context).
const symbolic::ChainModel* chain_model(const DefinitionContext* context, const std::string& name);
/// Its floating and ball joints: (joint, its quaternion coordinates qw, qx, qy, qz), on the tree
/// algorithms as on the symbolic derivation.
std::vector<std::pair<std::string, std::vector<std::string>>> chain_quaternions(
    const DefinitionContext* context, const std::string& name);
/// Its link tree: (parent link, child link) per joint, then (link, point name) per named point.
std::vector<std::pair<std::string, std::string>> chain_edges(const DefinitionContext* context,
                                                             const std::string& name);
/// The coordinates of its mobile base's x, y translation / of its prismatic joints (lengths, m).
std::vector<std::string> chain_base_coordinates(const DefinitionContext* context,
                                                const std::string& name);
std::vector<std::string> chain_prismatic_coordinates(const DefinitionContext* context,
                                                     const std::string& name);
/// The limits of serial_chain subsystem `name`'s coordinates (its robot file's joint limits,
/// ChainDef::coordinate_limits); empty if it has none, or no context.
std::vector<CoordinateLimits> chain_coordinate_limits(const DefinitionContext* context,
                                                      const std::string& name);
/// What the robot file readers noted (meshes ignored, limits taken as absent), each line once.
std::vector<std::string> robot_file_notes(const DefinitionContext* context);
/// The mass and inertia (about the CoM, body frame, row-major) of a free body, as numbers.
struct FreeBodyInertia {
  double mass = 0;
  std::array<double, 9> inertia{};
};
/// Those of free_body subsystem `name` (nullopt if none, no context, or not numbers).
std::optional<FreeBodyInertia> free_body_inertia(const DefinitionContext* context,
                                                 const std::string& name);
/// The shape a free body's `shape:` key gives it on the replay page (docs/free-bodies.md): box,
/// sphere or cylinder (along the body's z), centred at its CoM, its extents along the body axes
/// (m): a box's edges, a sphere's diameter (3 times), a cylinder's (2 r, 2 r, h).
struct FreeBodyShape {
  std::string shape;
  std::array<double, 3> size{0, 0, 0};
};
/// That of free_body subsystem `name` (nullopt if it has no `shape:`, or no context).
std::optional<FreeBodyShape> free_body_shape(const DefinitionContext* context,
                                             const std::string& name);
/// The robot file serial_chain subsystem `name` was read from: ("urdf" or "mjcf", its path);
/// nullopt for a chain of `joints:` (or no context).
std::optional<std::pair<std::string, std::string>> chain_robot_file(
    const DefinitionContext* context, const std::string& name);
/// The bodies (name, CoM in the world) of definitions subsystem `name`.
std::vector<std::pair<std::string, symbolic::Vec3Ex>> definitions_bodies(
    const DefinitionContext* context, const std::string& name);
/// The wheels of a wheeled platform (docs/wheeled-platforms.md), for drawing them: their radius
/// and each wheel's heading β (its axle along (−sin β, cos β) in the platform frame), in the order
/// of the bodies wheel1..N.
struct PlatformWheels {
  double radius = 0.0;
  std::vector<double> headings;
};
/// Records those of wheeled platform `name` in `context` (if given).
void record_platform_wheels(DefinitionContext* context, const std::string& name,
                            PlatformWheels wheels);
/// Those of wheeled platform `name` (nullopt if it is none, or no context).
std::optional<PlatformWheels> platform_wheels(const DefinitionContext* context,
                                              const std::string& name);
/// The bodies of definitions subsystem `name` as defined (mass, CoM, rotation, inertia; parameters
/// substituted), in the order of definitions_bodies.
std::vector<symbolic::BodyDef> definitions_body_defs(const DefinitionContext* context,
                                                     const std::string& name);

/// A subsystem node with type: serial_chain (joints in the file, or urdf: FILE). Its points are
/// recorded in `context` for points_coincide and point_trajectory.
std::shared_ptr<const Subsystem> load_chain_subsystem(const Loader& L, const Node& s,
                                                      const std::string& name,
                                                      const std::vector<std::string>& coordinates,
                                                      double gravity, DefinitionContext& context,
                                                      const InstanceSpec* instance = nullptr);

/// True for points_coincide, point_trajectory and angle_relation.
bool is_constraint_kind(const std::string& type);

/// A constraint node of one of the kinds above; `q0` is the initial state (origin: initial).
std::shared_ptr<const Constraint> load_constraint_kind(
    const Loader& L, const Node& c, const std::string& name, const std::string& type,
    const std::vector<std::string>& system_coordinates, DefinitionContext& context, const Vec& q0);

/// Fails at `s` if the subsystem's mass matrix is not positive definite at q (names the
/// coordinate).
void check_mass_matrix(const Loader& L, const Node& s, const Subsystem& sub, const Vec& q);

// The pieces other loaders share (forces_loader.cpp): an expression (errors at its column), the
// parameters: and let: of a node, a point (SUBSYSTEM.POINT or [x, y, z]), a time function.
GiNaC::ex parse_expression(const Loader& L, const symbolic::DefinitionScope& scope, const Node& n);
void load_parameters(const Loader& L, const Node& parent, symbolic::DefinitionScope& scope);
symbolic::Vec3Ex load_point_expression(const Loader& L, const Node& n,
                                       const symbolic::DefinitionScope& scope,
                                       DefinitionContext& context);
GiNaC::ex load_time_function_expression(const Loader& L, const Node& n,
                                        const symbolic::DefinitionScope& scope);

}  // namespace ukdyn::io_detail
