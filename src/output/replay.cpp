#include "ukdyn/output/replay.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <nlohmann/json.hpp>

#include "output/replay_assets.hpp"
#include "ukdyn/output/csv_writer.hpp"
#include "ukdyn/output/geometry.hpp"
#include "ukdyn/output/trajectory_table.hpp"

namespace ukdyn {

namespace {

// RFC 4648 base64 (for the import map's data: URLs).
std::string base64(std::string_view in) {
  static constexpr char k[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const auto a = static_cast<unsigned char>(in[i]), b = static_cast<unsigned char>(in[i + 1]),
               c = static_cast<unsigned char>(in[i + 2]);
    out += k[a >> 2];
    out += k[((a & 3) << 4) | (b >> 4)];
    out += k[((b & 15) << 2) | (c >> 6)];
    out += k[c & 63];
  }
  if (i + 1 == in.size()) {
    const auto a = static_cast<unsigned char>(in[i]);
    out += k[a >> 2];
    out += k[(a & 3) << 4];
    out += "==";
  } else if (i + 2 == in.size()) {
    const auto a = static_cast<unsigned char>(in[i]), b = static_cast<unsigned char>(in[i + 1]);
    out += k[a >> 2];
    out += k[((a & 3) << 4) | (b >> 4)];
    out += k[(b & 15) << 2];
    out += '=';
  }
  return out;
}

std::string html_escape(const std::string& s) {
  std::string o;
  for (char c : s) {
    switch (c) {
      case '<':
        o += "&lt;";
        break;
      case '>':
        o += "&gt;";
        break;
      case '&':
        o += "&amp;";
        break;
      case '"':
        o += "&quot;";
        break;
      default:
        o += c;
    }
  }
  return o;
}

// A JSON string literal, '<' escaped so that no "</script" can end the data block early.
std::string js_string(const std::string& s) {
  std::string j = nlohmann::json(s).dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  std::string o;
  for (char c : j) {
    if (c == '<') {
      o += "\\u003c";
    } else {
      o += c;
    }
  }
  return o;
}

// A number with 6 significant digits (sub-millimetre for metres; plots), null if not finite.
void number(std::string& o, double v) {
  if (!std::isfinite(v)) {
    o += "null";
    return;
  }
  fmt::format_to(std::back_inserter(o), "{:.6g}", v == 0.0 ? 0.0 : v);
}

// OUT/trajectory.csv, or the incomplete file of a run that did not finish.
std::filesystem::path locate_trajectory_csv(const std::filesystem::path& out_dir) {
  std::filesystem::path csv = out_dir / "trajectory.csv";
  std::error_code ec;  // what is there is checked when it is read (detail::InputStream)
  if (!std::filesystem::exists(std::filesystem::symlink_status(csv, ec))) {
    const auto inc = out_dir / CsvWriter::incomplete_name("trajectory.csv");
    if (!std::filesystem::exists(std::filesystem::symlink_status(inc, ec))) {
      throw Error(fmt::format("{}: no trajectory.csv (nor {}): simulate first", out_dir.string(),
                              inc.filename().string()));
    }
    csv = inc;
  }
  return csv;
}

// The CSV column of every coordinate of the scenario, in coordinate order.
std::vector<std::size_t> coordinate_columns(const TrajectoryTable& tab, const Scenario& sc,
                                            const std::filesystem::path& csv) {
  const auto col = [&](const std::string& n) -> long {
    auto it = std::find(tab.header.begin(), tab.header.end(), n);
    return it == tab.header.end() ? -1 : static_cast<long>(it - tab.header.begin());
  };
  std::vector<std::size_t> qcol;
  for (const auto& n : sc.system->coordinate_names()) {
    const long c = col(n);
    if (c < 0) {
      throw Error(
          fmt::format("{}: no column '{}': not a run of scenario '{}'", csv.string(), n, sc.name));
    }
    qcol.push_back(static_cast<std::size_t>(c));
  }
  return qcol;
}

// The data block's opening: scenario identity, stride, what is left out, points and segments.
void append_model_json(std::string& d, const Scenario& sc, const ReplayOptions& options,
                       const ReplayResult& res, const Geometry& geo) {
  d += "{\"name\":" + js_string(sc.name) + ",\"scenario\":" + js_string(sc.path.string()) +
       ",\"hash\":" + js_string(sc.hash) + ",\"status\":" + js_string(options.status) +
       fmt::format(",\"stride\":{},\"source_rows\":{}", res.stride, res.source_rows);
  d += ",\"left_out\":[";
  for (std::size_t i = 0; i < res.left_out.size(); ++i) {
    d += (i ? "," : "") + js_string(res.left_out[i]);
  }
  d += "],\"points\":[";
  for (std::size_t i = 0; i < geo.points().size(); ++i) {
    const auto& p = geo.points()[i];
    d += (i ? ",{\"name\":" : "{\"name\":") + js_string(p.name) + ",\"kind\":" + js_string(p.kind) +
         "}";
  }
  d += "],\"segments\":[";
  for (std::size_t i = 0; i < geo.segments().size(); ++i) {
    const auto& s = geo.segments()[i];
    d += fmt::format("{}[{},{},{}]", i ? "," : "", s.a, s.b, js_string(s.kind));
  }
  d += "],\"solids\":[";
  for (std::size_t i = 0; i < geo.solids().size(); ++i) {
    const auto& s = geo.solids()[i];
    d += (i ? ",{\"name\":" : "{\"name\":") + js_string(s.name) +
         ",\"shape\":" + js_string(s.shape) + ",\"size\":[";
    for (int k = 0; k < 3; ++k) {
      if (k) d += ',';
      number(d, s.size(k));
    }
    d += fmt::format("],\"point\":{},\"kind\":", s.point) + js_string(s.kind) + "}";
  }
}

// Comma-separated values of column c over every frame.
void append_column_values(std::string& d, const TrajectoryTable& tab, std::size_t c) {
  for (std::size_t f = 0; f < tab.rows.size(); ++f) {
    if (f) d += ',';
    number(d, tab.rows[f][c]);
  }
}

// Per frame, the numbers `values(q, out)` gives for q of the CSV row (point positions, solid
// orientations), flattened into one array.
void append_per_frame_json(std::string& d, const TrajectoryTable& tab,
                           const std::vector<std::size_t>& qcol, Index dof,
                           const std::function<void(CVecRef, std::vector<double>&)>& values) {
  Vec q(dof);
  std::vector<double> v;
  for (std::size_t f = 0; f < tab.rows.size(); ++f) {
    for (std::size_t i = 0; i < qcol.size(); ++i) q(static_cast<Index>(i)) = tab.rows[f][qcol[i]];
    values(q, v);
    d += f ? ",[" : "[";
    for (std::size_t i = 0; i < v.size(); ++i) {
      if (i) d += ',';
      number(d, v[i]);
    }
    d += ']';
  }
}

// Every column but t and q (they are drawn) for the plots.
void append_plot_columns_json(std::string& d, const TrajectoryTable& tab,
                              const std::vector<std::size_t>& qcol) {
  bool first = true;
  for (std::size_t c = 1; c < tab.header.size(); ++c) {
    if (std::find(qcol.begin(), qcol.end(), c) != qcol.end()) continue;
    d += (first ? "" : ",") + js_string(tab.header[c]) + ":[";
    first = false;
    append_column_values(d, tab, c);
    d += ']';
  }
}

// The plots shown at first: position residuals, constraint forces, energy.
void append_plot_groups_json(std::string& d, const TrajectoryTable& tab) {
  const auto group = [&](const std::string& title, auto pick) {
    std::string g = js_string(title) + ":[";
    bool any = false;
    for (const auto& h : tab.header) {
      if (pick(h)) {
        g += (any ? "," : "") + js_string(h);
        any = true;
      }
    }
    return g + "]";
  };
  d += group("position residuals Φ [m or rad]",
             [](const std::string& h) { return h.rfind("res_", 0) == 0; });
  d += "," + group("velocity residuals of the nonholonomic rows [m/s or rad/s]",
                   [](const std::string& h) { return h.rfind("vres_", 0) == 0; });
  d += "," + group("constraint force Qc [N or N·m]",
                   [](const std::string& h) { return h.rfind("Qc_", 0) == 0; });
  d += "," + group("energy [J]", [](const std::string& h) {
         return h == "T" || h == "V" || h == "E" || h == "E_balance";
       });
}

// The page's data block (a JSON object): the model, times, positions, plot columns and groups.
std::string replay_data_json(const Scenario& sc, const ReplayOptions& options,
                             const ReplayResult& res, const Geometry& geo,
                             const TrajectoryTable& tab, const std::vector<std::size_t>& qcol) {
  std::string d;
  d.reserve(1 << 20);
  append_model_json(d, sc, options, res, geo);
  d += "],\"t\":[";
  append_column_values(d, tab, 0);
  d += "],\"pos\":[";
  std::vector<Vec3> xyz;
  append_per_frame_json(d, tab, qcol, sc.system->dof(), [&](CVecRef q, std::vector<double>& v) {
    geo.evaluate(q, xyz);  // x, y, z of every point
    v.resize(3 * xyz.size());
    for (std::size_t i = 0; i < xyz.size(); ++i)
      for (int k = 0; k < 3; ++k) v[3 * i + static_cast<std::size_t>(k)] = xyz[i](k);
  });
  d += "],\"rot\":[";
  std::vector<std::array<double, 4>> rot;
  append_per_frame_json(d, tab, qcol, sc.system->dof(), [&](CVecRef q, std::vector<double>& v) {
    geo.evaluate_orientations(q, rot);  // w, x, y, z of every solid
    v.resize(4 * rot.size());
    for (std::size_t i = 0; i < rot.size(); ++i)
      for (std::size_t k = 0; k < 4; ++k) v[4 * i + k] = rot[i][k];
  });
  d += "],\"columns\":{";
  append_plot_columns_json(d, tab, qcol);
  d += "},\"groups\":{";
  append_plot_groups_json(d, tab);
  d += "}}";
  return d;
}

// The import map: three.js and its OrbitControls as data: URLs.
std::string replay_import_map() {
  return "{\"imports\":{\"three\":\"data:text/javascript;base64," +
         base64(replay_assets::three_js) +
         "\",\"three/addons/controls/OrbitControls.js\":\"data:text/javascript;base64," +
         base64(replay_assets::orbit_controls_js) + "\"}}";
}

using Placeholder = std::pair<std::string_view, std::string_view>;

// The template with every placeholder replaced by its value. The template's placeholders are found
// in the template itself, so nothing a value holds can be taken for one.
std::string fill_page_template(std::string_view tpl, const std::vector<Placeholder>& values,
                               std::size_t reserve) {
  std::string page;
  page.reserve(reserve);
  std::size_t pos = 0, filled = 0;
  while (pos < tpl.size()) {
    std::size_t next = std::string_view::npos;
    const Placeholder* which = nullptr;
    for (const auto& kv : values) {
      const auto at = tpl.find(kv.first, pos);
      if (at < next) {
        next = at;
        which = &kv;
      }
    }
    if (!which) {
      page += tpl.substr(pos);
      break;
    }
    page += tpl.substr(pos, next - pos);
    page += which->second;
    pos = next + which->first.size();
    ++filled;
  }
  if (filled != values.size()) throw Error("replay page template: a placeholder is missing");
  return page;
}

// OUT/replay.html written atomically (OutputRefused for a folder ukdyn will not use).
void write_page_file(const std::filesystem::path& out_dir, const std::string& page) {
  OutputDir out(out_dir);
  out.require_file_or_absent(out.fd(), "", kReplayFile);
  AtomicFile f(out, out.fd(), "", kReplayFile);
  f.write(page);
  f.commit();
  out.sync();
}

}  // namespace

bool replay_available() { return !replay_assets::three_js.empty(); }

ReplayResult write_replay(const Scenario& sc, const std::filesystem::path& out_dir,
                          const ReplayOptions& options) {
  if (!replay_available()) {
    throw Error(
        "ukdyn replay: this ukdyn was built without three.js (web/node_modules/three was missing "
        "when it was configured): run `npm ci` in web/ (scripts/install-deps.sh does) and rebuild");
  }
  const std::filesystem::path csv = locate_trajectory_csv(out_dir);
  const std::size_t rows = count_csv_rows(csv);
  if (rows == 0) throw Error(fmt::format("{}: no data rows", csv.string()));
  const std::size_t max_frames = std::max<std::size_t>(options.max_frames, 2);
  const std::size_t stride = rows <= max_frames ? 1 : (rows + max_frames - 2) / (max_frames - 1);
  const TrajectoryTable tab = read_trajectory(csv, stride);
  const std::vector<std::size_t> qcol = coordinate_columns(tab, sc, csv);

  ReplayResult res;
  const Geometry geo = build_geometry(sc, &res.left_out);
  res.frames = tab.rows.size();
  res.source_rows = tab.source_rows;
  res.stride = stride;

  const std::string d = replay_data_json(sc, options, res, geo, tab, qcol);
  const std::string importmap = replay_import_map();
  const std::string title = html_escape(sc.name);
  const std::vector<Placeholder> values{{"@TITLE@", title},
                                        {"@DATA@", d},
                                        {"@IMPORTMAP@", importmap},
                                        {"@APP@", replay_assets::app_js}};
  const std::string_view tpl = replay_assets::page_html;
  const std::string page = fill_page_template(
      tpl, values, tpl.size() + d.size() + importmap.size() + replay_assets::app_js.size());

  write_page_file(out_dir, page);
  res.file = out_dir / kReplayFile;
  res.bytes = page.size();
  return res;
}

}  // namespace ukdyn
