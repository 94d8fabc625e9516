#include "ukdyn/robot_files/mjcf.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <limits>
#include <numbers>
#include <set>
#include <vector>

#include "core/input_file.hpp"
#include "ukdyn/robot_files/visuals.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"

#ifdef UKDYN_HAVE_MUJOCO
#include <mujoco/mujoco.h>

#include <cstring>

#include "robot_files/mjcf_files.hpp"
#endif

namespace ukdyn::symbolic {

#ifndef UKDYN_HAVE_MUJOCO

bool mjcf_supported() { return false; }

void append_mjcf(ChainDef&, const std::string& path, bool) {
  throw DefinitionError(path +
                        ": this ukdyn was built without MuJoCo, so it cannot read MJCF files "
                        "(install libmujoco-dev, scripts/install-deps.sh, and rebuild)");
}

std::vector<LinkVisual> mjcf_visuals(const std::string& path) {
  throw DefinitionError(path +
                        ": this ukdyn was built without MuJoCo, so it cannot read MJCF files "
                        "(install libmujoco-dev, scripts/install-deps.sh, and rebuild)");
}

#else

namespace {

using GiNaC::ex;

// Decodes what tinyxml2 (MuJoCo's XML reader) decodes in an attribute value: &lt; &gt; &amp;
// &quot; &apos; and character references &#N; &#xH; (as UTF-8). Anything else stays as written.
std::string decode_xml_entities(const std::string& v) {
  static const std::pair<const char*, char> named[] = {
      {"lt", '<'}, {"gt", '>'}, {"amp", '&'}, {"quot", '"'}, {"apos", '\''}};
  std::string out;
  for (std::size_t i = 0; i < v.size(); ++i) {
    const std::size_t semi = v[i] == '&' ? v.find(';', i) : std::string::npos;
    if (semi == std::string::npos || semi - i > 10) {
      out += v[i];
      continue;
    }
    const std::string ent = v.substr(i + 1, semi - i - 1);
    bool done = false;
    for (const auto& [name, ch] : named) {
      if (ent == name) {
        out += ch;
        done = true;
      }
    }
    if (!done && ent.size() > 1 && ent[0] == '#') {
      const bool hex = ent[1] == 'x' || ent[1] == 'X';
      const std::string digits = ent.substr(hex ? 2 : 1);
      const bool ok = !digits.empty() && std::all_of(digits.begin(), digits.end(), [&](char c) {
        return hex ? std::isxdigit(static_cast<unsigned char>(c)) != 0
                   : std::isdigit(static_cast<unsigned char>(c)) != 0;
      });
      const unsigned long cp = ok ? std::stoul(digits, nullptr, hex ? 16 : 10) : 0;
      if (ok && cp > 0 && cp <= 0x10FFFF) {
        if (cp < 0x80) {
          out += static_cast<char>(cp);
        } else if (cp < 0x800) {
          out += static_cast<char>(0xC0 | (cp >> 6));
          out += static_cast<char>(0x80 | (cp & 0x3F));
        } else if (cp < 0x10000) {
          out += static_cast<char>(0xE0 | (cp >> 12));
          out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
          out += static_cast<char>(0x80 | (cp & 0x3F));
        } else {
          out += static_cast<char>(0xF0 | (cp >> 18));
          out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
          out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
          out += static_cast<char>(0x80 | (cp & 0x3F));
        }
        done = true;
      }
    }
    if (done) {
      i = semi;
    } else {
      out += v[i];
    }
  }
  return out;
}

std::size_t skip_space(const std::string& s, std::size_t k) {
  while (k < s.size() && std::isspace(static_cast<unsigned char>(s[k]))) ++k;
  return k;
}

// The attributes of the elements named `element` of an MJCF text as MuJoCo reads them: the element
// name compared case-insensitively (MuJoCo's strcasecmp), quoted values that may hold '>', the
// attribute names exactly (tinyxml2), entities decoded. A linear scan (no backtracking regex on a
// 16 MiB file). A commented-out element is read too: one file more is checked, never one less.
using Attributes = std::vector<std::pair<std::string, std::string> >;
std::vector<Attributes> elements(const std::string& xml, const char* element) {
  std::vector<Attributes> out;
  const std::size_t n = xml.size();
  std::size_t i = 0;
  while ((i = xml.find('<', i)) != std::string::npos) {
    std::size_t k = skip_space(xml, i + 1);
    i = k;
    std::size_t w = 0;
    while (element[w] && k + w < n &&
           std::tolower(static_cast<unsigned char>(xml[k + w])) == element[w])
      ++w;
    if (element[w] || (k + w < n && !std::isspace(static_cast<unsigned char>(xml[k + w])) &&
                       xml[k + w] != '/' && xml[k + w] != '>'))
      continue;
    k += w;
    Attributes& attrs = out.emplace_back();
    for (;;) {  // attributes: name = "value" | 'value'
      k = skip_space(xml, k);
      std::size_t e = k;
      while (e < n && !std::isspace(static_cast<unsigned char>(xml[e])) && xml[e] != '=' &&
             xml[e] != '/' && xml[e] != '>' && xml[e] != '<')
        ++e;
      const std::string name = xml.substr(k, e - k);
      k = skip_space(xml, e);
      if (name.empty() || k >= n || xml[k] != '=') break;
      k = skip_space(xml, k + 1);
      if (k >= n || (xml[k] != '"' && xml[k] != '\'')) break;
      const std::size_t close = xml.find(xml[k], k + 1);
      if (close == std::string::npos) break;
      attrs.emplace_back(name, decode_xml_entities(xml.substr(k + 1, close - k - 1)));
      k = close + 1;
    }
    i = k;
  }
  return out;
}

// The file attributes of the <include> elements.
std::vector<std::string> include_files(const std::string& xml) {
  std::vector<std::string> out;
  for (const Attributes& a : elements(xml, "include"))
    for (const auto& [name, value] : a)
      if (name == "file") out.push_back(value);
  return out;
}

// The name MuJoCo's virtual file system keys a file by (engine_vfs.c, vfs_strippath): the text
// after the last '/' or '\\', in lower case.
std::string vfs_key(const std::string& path) {
  const std::size_t slash = path.find_last_of("/\\");
  std::string key = slash == std::string::npos ? path : path.substr(slash + 1);
  for (char& c : key) {
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
  }
  return key;
}

// `bytes` read from `file` into `read`, once per name MuJoCo's virtual file system tells apart: a
// second file of the same name is refused (naming it as `name`) unless its bytes are the same.
void keep_read(const std::filesystem::path& file, const std::string& bytes, const std::string& name,
               std::vector<mjcf_detail::MjcfFile>& read) {
  const std::string key = vfs_key(file.string());
  auto same = std::find_if(read.begin(), read.end(), [&](const mjcf_detail::MjcfFile& f) {
    return vfs_key(f.path.string()) == key;
  });
  if (same != read.end() && same->bytes != bytes) {
    throw DefinitionError(name +
                          ": MuJoCo's virtual file system knows a file by its name without "
                          "the folder, case-insensitively, and " +
                          same->path.string() +
                          " has that name with other contents (or the file changed while "
                          "ukdyn read it): rename one of them");
  }
  if (same == read.end()) read.push_back({file, bytes});
}

// Every file MuJoCo would open is read here, once per occurrence, before MuJoCo opens any: the
// model file and, recursively, its <include file="..."/> (relative to the model file's folder, as
// MuJoCo resolves them) must be regular files of at most 16 MiB; a FIFO, a folder or a device is
// named as what it is (a FIFO would block MuJoCo's reader forever), an include cycle or more than
// 32 levels is refused, and so are more than 256 files in all (a file that includes itself twice
// would double at every level). MuJoCo then compiles these bytes (compile_mjcf), not the files.
void read_model_files(const std::filesystem::path& file, const std::filesystem::path& folder,
                      int depth, const std::string& via, std::vector<mjcf_detail::MjcfFile>& read,
                      int& files) {
  const std::string name = file.string() + via;
  if (depth > 32) throw DefinitionError(name + ": more than 32 levels of <include> (a cycle?)");
  if (++files > 256) throw DefinitionError(name + ": more than 256 files with its <include>s");
  std::string xml;
  try {
    xml = detail::read_input_file(file, {"MJCF file", 16 * detail::kMiB, name});
  } catch (const detail::InputFileError& e) {
    throw DefinitionError(e.what());
  }
  if (xml.empty()) throw DefinitionError(name + ": is empty, not a MJCF file");
  keep_read(file, xml, name, read);
  for (const std::string& f : include_files(xml)) {
    std::filesystem::path inc = f;
    if (inc.is_relative()) inc = folder / inc;
    read_model_files(inc, folder, depth + 1, " (included from " + file.filename().string() + ")",
                     read, files);
  }
}

// The asset files MuJoCo opens by name while it compiles (MuJoCo 2.2's mesh, skin, height field
// and texture loaders look in the virtual file system first, then on disk): <mesh>, <skin> and
// <hfield> file= relative to the <compiler>'s meshdir, <texture> file= (and a cube's fileright ..
// fileback) relative to texturedir, a relative folder relative to the model file's folder,
// strippath="true" dropping a file's folder (MuJoCo's XML reference, "compiler"; MuJoCo 2.2 has
// no assetdir and refuses it). Each is read by the checked reader into `read`, so that MuJoCo finds
// it in its virtual file system and opens none by name: missing, a FIFO, a folder, a device,
// empty or larger than 256 MiB is refused naming the file, the element and the model file naming
// it; so is a second asset of the same name with other bytes (MuJoCo would take one for both).
void read_asset_files(const std::filesystem::path& folder,
                      std::vector<mjcf_detail::MjcfFile>& read) {
  const std::size_t model_files = read.size();
  std::string meshdir, texturedir, strippath;
  for (std::size_t f = 0; f < model_files; ++f) {  // the last <compiler> setting wins
    for (const Attributes& a : elements(read[f].bytes, "compiler")) {
      for (const auto& [name, value] : a) {
        if (name == "meshdir") meshdir = value;
        if (name == "texturedir") texturedir = value;
        if (name == "strippath") strippath = value;
      }
    }
  }
  struct Kind {
    const char* element;
    const char* what;
    const std::string& dir;
    bool cube;  // a cube texture's six faces, each a file of its own
  };
  const Kind kinds[] = {{"mesh", "mesh file", meshdir, false},
                        {"skin", "skin file", meshdir, false},
                        {"hfield", "height field file", meshdir, false},
                        {"texture", "texture file", texturedir, true}};
  const std::set<std::string> cube_faces = {"fileright", "fileleft",  "fileup",
                                            "filedown",  "filefront", "fileback"};
  std::size_t total = 0;
  for (std::size_t f = 0; f < model_files; ++f) {
    const std::string from = read[f].path.filename().string();
    for (const Kind& kind : kinds) {
      for (const Attributes& a : elements(read[f].bytes, kind.element)) {
        for (const auto& [name, value] : a) {
          if (name != "file" && !(kind.cube && cube_faces.count(name) > 0)) continue;
          std::filesystem::path file = value;
          if (strippath == "true") file = file.filename();
          const std::filesystem::path dir = kind.dir;
          if (file.is_relative()) file = dir.is_absolute() ? dir / file : folder / dir / file;
          const std::string shown = file.string() + " (<" + kind.element + " " + name + "=\"" +
                                    value + "\"> in " + from + ")";
          std::string bytes;
          try {
            bytes = detail::read_input_file(file, {kind.what, 256 * detail::kMiB, shown});
          } catch (const detail::InputFileError& e) {
            throw DefinitionError(e.what());
          }
          if (bytes.empty()) throw DefinitionError(shown + ": is empty, not a " + kind.what);
          if ((total += bytes.size()) > 1024 * detail::kMiB)
            throw DefinitionError(shown + ": the model's asset files exceed 1 GiB in all");
          keep_read(file, bytes, shown, read);
        }
      }
    }
  }
}

// Rotation matrix (row-major) of a unit quaternion (w, x, y, z).
std::array<double, 9> quat_matrix(const double* q) {
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  const double n = w * w + x * x + y * y + z * z;
  const double s = n > 0.0 ? 2.0 / n : 0.0;
  return {1 - s * (y * y + z * z), s * (x * y - w * z),     s * (x * z + w * y),
          s * (x * y + w * z),     1 - s * (x * x + z * z), s * (y * z - w * x),
          s * (x * z - w * y),     s * (y * z + w * x),     1 - s * (x * x + y * y)};
}

// Roll, pitch, yaw with R = Rz(yaw) Ry(pitch) Rx(roll) (chain.hpp's convention).
Vec3Ex rpy_of(const double* quat) {
  const auto R = quat_matrix(quat);
  double roll = 0.0, pitch = 0.0, yaw = 0.0;
  const double s = -R[6];
  if (std::abs(s) < 1.0 - 1e-12) {
    pitch = std::asin(s);
    roll = std::atan2(R[7], R[8]);
    yaw = std::atan2(R[3], R[0]);
  } else {  // pitch = ±π/2: only roll ∓ yaw is defined; take roll = 0
    pitch = s > 0 ? std::numbers::pi / 2 : -std::numbers::pi / 2;
    yaw = std::atan2(-R[1], R[4]);
  }
  return {exact_number(roll), exact_number(pitch), exact_number(yaw)};
}

Vec3Ex vec_of(const double* v) {
  return {exact_number(v[0]), exact_number(v[1]), exact_number(v[2])};
}

// The compiled model and its file, for the messages.
struct MjcfSource {
  const mjModel& m;
  const std::string& path;
  [[nodiscard]] std::string name_of(int type, int id, const std::string& fallback) const {
    const char* n = mj_id2name(&m, type, id);
    return n && *n ? std::string(n) : fallback;
  }
};

// An imported name that becomes a constraint name (CSV columns, figure files) obeys the
// scenario's name rule (docs/scenario-format.md, "Names"): 1 to 64 characters from A-Z a-z 0-9 _ .
// -, not starting with '.' or '-'. A name with a comma, a quote or a newline is refused here, not
// written into a CSV header that ukdyn's own reader must then split.
void check_imported_name(const std::string& name, const std::string& what,
                         const std::string& path) {
  bool ok = !name.empty() && name.size() <= 64 && name[0] != '.' && name[0] != '-';
  std::string shown;
  for (const char ch : name) {
    ok =
        ok && (std::isalnum(static_cast<unsigned char>(ch)) || ch == '_' || ch == '.' || ch == '-');
    const auto u = static_cast<unsigned char>(ch);
    if (shown.size() < 48) shown += u >= 0x20 && u < 0x7f ? std::string(1, ch) : "?";
  }
  if (!ok)
    throw DefinitionError(path + ": " + what + " is named '" + shown +
                          "': a name must be 1 to 64 characters from A-Z a-z 0-9 _ . - and not "
                          "start with '.' or '-' (rename it in the MJCF file)");
}

// Coordinates for the joints, in MuJoCo's order: the chain's, less the mobile base's.
std::vector<std::string> joint_coordinates(const ChainDef& chain) {
  std::set<std::string> taken;
  if (chain.base.enabled) {
    taken.insert(chain.base.x);
    taken.insert(chain.base.y);
    if (!chain.base.yaw.empty()) taken.insert(chain.base.yaw);
  }
  std::vector<std::string> free;
  for (const auto& c : chain.coordinates())
    if (!taken.count(c)) free.push_back(c);
  return free;
}

// Refuses what the chain cannot hold: a free joint off its body's origin, a qpos count other
// than the chain's joint coordinates, equalities other than active welds and connects.
void check_supported(const MjcfSource& src, std::size_t ncoords) {
  const mjModel& m = src.m;
  const std::string& path = src.path;
  for (int j = 0; j < m.njnt; ++j) {
    const double* a = m.jnt_pos + 3 * j;
    if (m.jnt_type[j] == mjJNT_FREE && (a[0] != 0.0 || a[1] != 0.0 || a[2] != 0.0)) {
      throw DefinitionError(path + ": joint '" + src.name_of(mjOBJ_JOINT, j, std::to_string(j)) +
                            "': a free joint with an anchor off the body origin is not supported");
    }
  }
  if (static_cast<int>(ncoords) != m.nq) {
    throw DefinitionError(path + ": the model has " + std::to_string(m.nq) +
                          " qpos coordinates (hinge and slide joints 1, ball 4, free 7) but the "
                          "chain declares " +
                          std::to_string(ncoords) + " joint coordinates");
  }
  for (int e = 0; e < m.neq; ++e) {  // weld and connect only (read: append_equalities)
    const std::string ename = src.name_of(mjOBJ_EQUALITY, e, "equality" + std::to_string(e));
    if (m.eq_type[e] != mjEQ_WELD && m.eq_type[e] != mjEQ_CONNECT) {
      throw DefinitionError(path + ": equality '" + ename +
                            "': only weld and connect equalities are read (joint and tendon "
                            "couplings: write them as constraints)");
    }
    if (!m.eq_active[e]) {
      throw DefinitionError(path + ": equality '" + ename +
                            "' is inactive: ukdyn cannot switch a constraint on during a run "
                            "(remove it, or make it active)");
    }
  }
}

// Where a body's next joint hangs: the previous joint's link (first: the parent body's link), and
// the previous joint's anchor in the body frame (nullptr before the first joint).
struct JointCursor {
  std::string prev;
  const double* prev_anchor = nullptr;
};

// The largest generalized force the actuators on joint j can apply (+inf if one of them is not
// limited, or none acts on it): per actuator with a joint transmission, |gear| times its force
// bound, forcerange when forcelimited, else ctrlrange times the gain of a plain motor (fixed gain,
// no bias, no activation dynamics) when ctrllimited.
double actuator_effort(const mjModel& m, int j) {
  const double inf = std::numeric_limits<double>::infinity();
  double sum = 0.0;
  bool any = false;
  for (int u = 0; u < m.nu; ++u) {
    if (m.actuator_trnid[2 * u] != j ||
        (m.actuator_trntype[u] != mjTRN_JOINT && m.actuator_trntype[u] != mjTRN_JOINTINPARENT))
      continue;
    any = true;
    const double* fr = m.actuator_forcerange + 2 * u;
    const double* cr = m.actuator_ctrlrange + 2 * u;
    const bool motor = m.actuator_gaintype[u] == mjGAIN_FIXED &&
                       m.actuator_biastype[u] == mjBIAS_NONE && m.actuator_dyntype[u] == mjDYN_NONE;
    double bound = inf;
    if (m.actuator_forcelimited[u]) {
      bound = std::max(std::abs(fr[0]), std::abs(fr[1]));
    } else if (motor && m.actuator_ctrllimited[u]) {
      bound =
          std::max(std::abs(cr[0]), std::abs(cr[1])) * std::abs(m.actuator_gainprm[mjNGAIN * u]);
    }
    sum += bound * std::abs(m.actuator_gear[6 * u]);
  }
  return any && sum > 0.0 ? sum : inf;
}

// Joint i of body b, as a chain joint to a link BODY__JOINT after the cursor's link.
void append_joint(ChainDef& chain, const MjcfSource& src, int b, int i, const std::string& bname,
                  const std::vector<std::string>& free, JointCursor& at) {
  const mjModel& m = src.m;
  const double* bpos = m.body_pos + 3 * b;
  const double* bquat = m.body_quat + 4 * b;
  const int j = m.body_jntadr[b] + i;
  const double* a = m.jnt_pos + 3 * j;
  const std::string jname = src.name_of(mjOBJ_JOINT, j, bname + "_joint" + std::to_string(i));
  const int type = m.jnt_type[j];
  const bool hinge = type == mjJNT_HINGE;
  const JointDef::Type jt = type == mjJNT_FREE   ? JointDef::Type::floating
                            : type == mjJNT_BALL ? JointDef::Type::ball
                            : hinge              ? JointDef::Type::revolute
                                                 : JointDef::Type::prismatic;
  // The joint frame sits at the anchor, oriented as the body frame.
  JointDef& jd = chain.add_joint(jname, jt, bname + "__" + jname);
  jd.parent = at.prev;
  const auto adr = static_cast<std::size_t>(m.jnt_qposadr[j]);
  if (type == mjJNT_FREE) {
    // qpos: the body origin in the parent (world) frame and the body's quaternion (w, x, y,
    // z), not relative to body_pos / body_quat; the joint frame is the parent's.
    for (std::size_t k = 0; k < 7; ++k) jd.coordinates.push_back(free[adr + k]);
    at = {jd.link, a};
    return;
  }
  if (type == mjJNT_BALL) {  // qpos: the quaternion of the rotation about the anchor
    for (std::size_t k = 0; k < 4; ++k) jd.coordinates.push_back(free[adr + k]);
  }
  if (i == 0) {
    const auto R = quat_matrix(bquat);
    const double p[3] = {bpos[0] + R[0] * a[0] + R[1] * a[1] + R[2] * a[2],
                         bpos[1] + R[3] * a[0] + R[4] * a[1] + R[5] * a[2],
                         bpos[2] + R[6] * a[0] + R[7] * a[1] + R[8] * a[2]};
    jd.origin.xyz = vec_of(p);
    jd.origin.rpy = rpy_of(bquat);
  } else {
    const double* pa = at.prev_anchor;
    const double d[3] = {a[0] - pa[0], a[1] - pa[1], a[2] - pa[2]};
    jd.origin.xyz = vec_of(d);
  }
  if (type != mjJNT_BALL) {
    jd.axis = vec_of(m.jnt_axis + 3 * j);
    const ex q = coordinate_symbol(chain.symbols(), free[adr]);
    const double q0 = m.qpos0[m.jnt_qposadr[j]];
    jd.value = q0 == 0.0 ? q : q - exact_number(q0);
    if (m.jnt_limited[j]) {  // range is on qpos; the joint's value is qpos − qpos0
      jd.limits.lower = m.jnt_range[2 * j] - q0;
      jd.limits.upper = m.jnt_range[2 * j + 1] - q0;
    }
    jd.limits.effort = actuator_effort(m, j);
  }
  at = {jd.link, a};
}

// Fails unless body b's compiled mass is >= 0 and its principal moments A, B, C are >= 0 and meet
// the triangle inequality A + B >= C (relative tolerance 1e-6 of the largest); names the file and
// the body. (MuJoCo's compiler refuses most such bodies itself, with its own message.)
void check_body_inertia(const MjcfSource& src, int b, const std::string& bname) {
  const double mass = src.m.body_mass[b];
  const double* I = src.m.body_inertia + 3 * b;
  const std::string where = src.path + ": body '" + bname + "'";
  if (!std::isfinite(mass) || mass < 0.0)
    throw DefinitionError(where + ": the mass must be a finite number >= 0, got " +
                          std::to_string(mass));
  const double largest = std::max({I[0], I[1], I[2]});
  for (int k = 0; k < 3; ++k) {
    const double a = I[k], b1 = I[(k + 1) % 3], c = I[(k + 2) % 3];
    if (!std::isfinite(a) || a < 0.0)
      throw DefinitionError(where + ": a principal moment of inertia is negative or not finite");
    if (b1 + c < a - 1e-6 * largest) {
      throw DefinitionError(where +
                            ": the inertia breaks the triangle inequality of a rigid body: "
                            "principal moments " +
                            std::to_string(b1) + " + " + std::to_string(c) + " < " +
                            std::to_string(a));
    }
  }
}

// The body frame (fixed to the last joint frame, or to the parent) with the body's inertia.
void append_body_frame(ChainDef& chain, const MjcfSource& src, int b, const std::string& bname,
                       const JointCursor& at) {
  const mjModel& m = src.m;
  const double* bpos = m.body_pos + 3 * b;
  const double* bquat = m.body_quat + 4 * b;
  JointDef& fd = chain.add_joint(bname + "__frame", JointDef::Type::fixed, bname);
  fd.parent = at.prev;
  if (m.body_jntnum[b] == 0) {
    fd.origin.xyz = vec_of(bpos);
    fd.origin.rpy = rpy_of(bquat);
  } else {
    const double d[3] = {-at.prev_anchor[0], -at.prev_anchor[1], -at.prev_anchor[2]};
    fd.origin.xyz = vec_of(d);
  }
  check_body_inertia(src, b, bname);
  fd.inertial.mass = exact_number(m.body_mass[b]);
  fd.inertial.com = vec_of(m.body_ipos + 3 * b);
  fd.inertial.rpy = rpy_of(m.body_iquat + 4 * b);
  const double* I = m.body_inertia + 3 * b;
  fd.inertial.inertia = {exact_number(I[0]), 0, 0, 0, exact_number(I[1]), 0, 0, 0,
                         exact_number(I[2])};
}

// Body b > 0: its joints, then its frame; link[b] becomes its name (link: the link of every
// body, body 0 the chain's root).
void append_body(ChainDef& chain, const MjcfSource& src, int b,
                 const std::vector<std::string>& free, std::vector<std::string>& link) {
  const mjModel& m = src.m;
  const std::string bname = src.name_of(mjOBJ_BODY, b, "body" + std::to_string(b));
  link[static_cast<std::size_t>(b)] = bname;
  JointCursor at{link[static_cast<std::size_t>(m.body_parentid[b])]};
  for (int i = 0; i < m.body_jntnum[b]; ++i) append_joint(chain, src, b, i, bname, free, at);
  append_body_frame(chain, src, b, bname, at);
}

// Equalities, from the compiled eq_data (MuJoCo's mj_instantiateEquality, body semantic):
//   connect: x1 + R1 d[0:3] = x2 + R2 d[3:6]  (the anchor in body 1's frame, and the same
//            point in body 2's frame, as the compiler computed it at qpos0): a ball constraint;
//   weld:    x1 + R1 d[3:6] = x2 + R2 d[0:3] and R1 R(d[6:10]) = R2  (relpose: body 2's pose
//            in body 1's frame, computed at qpos0 when not given): frame a = body 1 moved by
//            (d[3:6], d[6:10]), frame b = body 2 moved by d[0:3]. torquescale (d[10]) only
//            scales MuJoCo's rotation rows, which for an ideal constraint changes no motion.
void append_equalities(ChainDef& chain, const MjcfSource& src,
                       const std::vector<std::string>& link) {
  const mjModel& m = src.m;
  for (int e = 0; e < m.neq; ++e) {
    const double* d = m.eq_data + mjNEQDATA * e;
    LinkConstraintDef lc;
    lc.name = src.name_of(mjOBJ_EQUALITY, e, "equality" + std::to_string(e));
    check_imported_name(lc.name, "equality " + std::to_string(e), src.path);
    // (Body 0, MuJoCo's world, is the chain's root: the base, or root_link at the mount.)
    lc.link_a = link[static_cast<std::size_t>(m.eq_obj1id[e])];
    lc.link_b = link[static_cast<std::size_t>(m.eq_obj2id[e])];
    if (m.eq_type[e] == mjEQ_CONNECT) {
      lc.kind = LinkConstraintDef::Kind::ball;
      lc.offset_a.xyz = vec_of(d);
      lc.offset_b.xyz = vec_of(d + 3);
    } else {
      lc.kind = LinkConstraintDef::Kind::weld;
      lc.offset_a.xyz = vec_of(d + 3);
      lc.offset_a.rpy = rpy_of(d + 6);
      lc.offset_b.xyz = vec_of(d);
    }
    chain.link_constraints.push_back(std::move(lc));
  }
}

}  // namespace

bool mjcf_supported() { return true; }

namespace mjcf_detail {

std::vector<MjcfFile> read_mjcf_files(const std::filesystem::path& model) {
  std::vector<MjcfFile> read;
  int files = 0;
  read_model_files(model, model.parent_path(), 0, "", read, files);
  read_asset_files(model.parent_path(), read);
  return read;
}

MjModelPtr compile_mjcf(const std::filesystem::path& model, const std::vector<MjcfFile>& files) {
  // mjVFS holds 2000 names of 1000 bytes: on the heap. MuJoCo looks every file up here first
  // (mjParseXML, mjIncludeXML); read_mjcf_files read all it includes and refused empty files
  // (mj_makeEmptyFileVFS ends the process on a size of 0).
  struct Vfs {
    std::unique_ptr<mjVFS> v = std::make_unique<mjVFS>();
    Vfs() { mj_defaultVFS(v.get()); }
    ~Vfs() { mj_deleteVFS(v.get()); }
    Vfs(const Vfs&) = delete;
    Vfs& operator=(const Vfs&) = delete;
  } vfs;
  for (const MjcfFile& f : files) {
    const std::string name = f.path.string();
    const int r = mj_makeEmptyFileVFS(vfs.v.get(), name.c_str(), static_cast<int>(f.bytes.size()));
    if (r != 0) {
      throw DefinitionError(name + (r == 1 ? ": too many files for MuJoCo's virtual file system"
                                           : ": a second file of this name for MuJoCo"));
    }
    const int id = mj_findFileVFS(vfs.v.get(), name.c_str());
    std::memcpy(vfs.v->filedata[id], f.bytes.data(), f.bytes.size());
  }
  char err[1000] = "";
  MjModelPtr m(mj_loadXML(model.string().c_str(), vfs.v.get(), err, sizeof err));
  if (!m) throw DefinitionError(model.string() + ": MuJoCo could not load it: " + err);
  return m;
}

}  // namespace mjcf_detail

void append_mjcf(ChainDef& chain, const std::string& path, bool gravity) {
  const mjcf_detail::MjModelPtr g =
      mjcf_detail::compile_mjcf(path, mjcf_detail::read_mjcf_files(path));
  const MjcfSource src{*g, path};
  const std::vector<std::string> free = joint_coordinates(chain);
  check_supported(src, free.size());
  if (gravity) chain.gravity = vec_of(g->opt.gravity);
  const std::string root = chain.base.enabled ? chain.base.link : chain.root_link;
  std::vector<std::string> link(static_cast<std::size_t>(g->nbody));
  link[0] = root;
  for (int b = 1; b < g->nbody; ++b) append_body(chain, src, b, free, link);
  append_equalities(chain, src, link);
  int meshes = 0;
  for (int k = 0; k < g->ngeom; ++k) meshes += g->geom_type[k] == mjGEOM_MESH ? 1 : 0;
  if (meshes > 0) {
    chain.notes.push_back(
        path + ": " + std::to_string(meshes) + (meshes == 1 ? " mesh" : " meshes") +
        " ignored: ukdyn reads kinematics and inertia only; the replay page draws meshes as "
        "their bounding boxes");
  }
}

namespace {

// Mesh geom k as its bounding box in the geom's frame: MuJoCo's compiled model holds the mesh's
// vertices in the geom frame (mesh_vert; the mesh's own offset is in geom_pos / geom_quat), so the
// box is [lo, hi] of them, centred at p + R (lo + hi) / 2 of the link frame. Left a mesh if it has
// no vertices.
void mesh_bounding_box(const mjModel& m, int k, LinkVisual& v) {
  const int id = m.geom_dataid[k];
  if (id < 0 || m.mesh_vertnum[id] <= 0) return;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(HUGE_VAL), hi = -lo;
  const float* vert = m.mesh_vert + 3 * m.mesh_vertadr[id];
  for (int i = 0; i < m.mesh_vertnum[id]; ++i) {
    const Eigen::Vector3d x(vert[3 * i], vert[3 * i + 1], vert[3 * i + 2]);
    lo = lo.cwiseMin(x);
    hi = hi.cwiseMax(x);
  }
  const Eigen::Quaterniond r(v.quat[0], v.quat[1], v.quat[2], v.quat[3]);
  const Eigen::Vector3d c =
      Eigen::Vector3d(v.xyz[0], v.xyz[1], v.xyz[2]) + r.normalized() * (0.5 * (lo + hi));
  v.shape = "box";
  v.bounding_box = true;
  v.xyz = {c.x(), c.y(), c.z()};
  v.size = {hi.x() - lo.x(), hi.y() - lo.y(), hi.z() - lo.z()};
}

// Geom k as a LinkVisual: MuJoCo's half-sizes (geom_size) as extents (docs/replay.md); capsules and
// cylinders along the geom's z (MuJoCo's fromto already turned into geom_pos / geom_quat).
LinkVisual geom_visual(const MjcfSource& src, int k) {
  const mjModel& m = src.m;
  LinkVisual v;
  const int b = m.geom_bodyid[k];
  v.link = b == 0 ? "" : src.name_of(mjOBJ_BODY, b, "body" + std::to_string(b));
  const double* p = m.geom_pos + 3 * k;
  const double* q = m.geom_quat + 4 * k;
  const double* h = m.geom_size + 3 * k;
  v.xyz = {p[0], p[1], p[2]};
  v.quat = {q[0], q[1], q[2], q[3]};
  switch (m.geom_type[k]) {
    case mjGEOM_BOX:
      v.shape = "box";
      v.size = {2 * h[0], 2 * h[1], 2 * h[2]};
      break;
    case mjGEOM_SPHERE:
      v.shape = "sphere";
      v.size = {2 * h[0], 2 * h[0], 2 * h[0]};
      break;
    case mjGEOM_ELLIPSOID:
      v.shape = "ellipsoid";
      v.size = {2 * h[0], 2 * h[1], 2 * h[2]};
      break;
    case mjGEOM_CYLINDER:  // radius, half-length
      v.shape = "cylinder";
      v.size = {2 * h[0], 2 * h[0], 2 * h[1]};
      break;
    case mjGEOM_CAPSULE:  // radius, half-length of the cylinder part
      v.shape = "capsule";
      v.size = {2 * h[0], 2 * h[0], 2 * h[1] + 2 * h[0]};
      break;
    case mjGEOM_MESH:
      v.shape = "mesh";
      v.detail = src.name_of(mjOBJ_MESH, m.geom_dataid[k], "");
      mesh_bounding_box(m, k, v);
      break;
    case mjGEOM_PLANE:
      v.shape = "plane";
      break;
    case mjGEOM_HFIELD:
      v.shape = "hfield";
      break;
    default:
      v.shape = "geom type " + std::to_string(m.geom_type[k]);
  }
  return v;
}

}  // namespace

std::vector<LinkVisual> mjcf_visuals(const std::string& path) {
  const mjcf_detail::MjModelPtr g =
      mjcf_detail::compile_mjcf(path, mjcf_detail::read_mjcf_files(path));
  const MjcfSource src{*g, path};
  std::vector<LinkVisual> out;
  for (int k = 0; k < g->ngeom; ++k) out.push_back(geom_visual(src, k));
  return out;
}

#endif

}  // namespace ukdyn::symbolic
