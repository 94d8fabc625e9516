#include "ukdyn/io/replay.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "ukdyn/io/csv_writer.hpp"
#include "ukdyn/io/geometry.hpp"
#include "ukdyn/io/replay_assets.hpp"
#include "ukdyn/io/trajectory_table.hpp"

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

}  // namespace

bool replay_available() { return !replay_assets::three_js.empty(); }

ReplayResult write_replay(const Scenario& sc, const std::filesystem::path& out_dir,
                          const ReplayOptions& options) {
  if (!replay_available()) {
    throw Error(
        "ukdyn replay: this ukdyn was built without three.js (web/node_modules/three was missing "
        "when it was configured): run `npm ci` in web/ (scripts/install-deps.sh does) and rebuild");
  }
  const System& sys = *sc.system;
  std::filesystem::path csv = out_dir / "trajectory.csv";
  if (!std::filesystem::is_regular_file(csv)) {
    const auto inc = out_dir / CsvWriter::incomplete_name("trajectory.csv");
    if (!std::filesystem::is_regular_file(inc)) {
      throw Error(fmt::format("{}: no trajectory.csv (nor {}): simulate first", out_dir.string(),
                              inc.filename().string()));
    }
    csv = inc;
  }
  const std::size_t rows = count_csv_rows(csv);
  if (rows == 0) throw Error(fmt::format("{}: no data rows", csv.string()));
  const std::size_t max_frames = std::max<std::size_t>(options.max_frames, 2);
  const std::size_t stride = rows <= max_frames ? 1 : (rows + max_frames - 2) / (max_frames - 1);
  const TrajectoryTable tab = read_trajectory(csv, stride);
  const auto& names = sys.coordinate_names();
  const auto col = [&](const std::string& n) -> long {
    auto it = std::find(tab.header.begin(), tab.header.end(), n);
    return it == tab.header.end() ? -1 : static_cast<long>(it - tab.header.begin());
  };
  std::vector<std::size_t> qcol;
  for (const auto& n : names) {
    const long c = col(n);
    if (c < 0) {
      throw Error(
          fmt::format("{}: no column '{}': not a run of scenario '{}'", csv.string(), n, sc.name));
    }
    qcol.push_back(static_cast<std::size_t>(c));
  }

  ReplayResult res;
  const Geometry geo = build_geometry(sc, &res.left_out);
  res.frames = tab.rows.size();
  res.source_rows = tab.source_rows;
  res.stride = stride;

  std::string d;
  d.reserve(1 << 20);
  d += "{\"name\":" + js_string(sc.name) + ",\"scenario\":" + js_string(sc.path.string()) +
       ",\"hash\":" + js_string(sc.hash) + ",\"status\":" + js_string(options.status) +
       fmt::format(",\"stride\":{},\"source_rows\":{}", stride, tab.source_rows);
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
  d += "],\"t\":[";
  for (std::size_t f = 0; f < tab.rows.size(); ++f) {
    if (f) d += ',';
    number(d, tab.rows[f][0]);
  }
  // Point positions per frame, from q of the CSV row.
  d += "],\"pos\":[";
  Vec q(sys.dof());
  std::vector<Vec3> xyz;
  for (std::size_t f = 0; f < tab.rows.size(); ++f) {
    for (std::size_t i = 0; i < qcol.size(); ++i) q(static_cast<Index>(i)) = tab.rows[f][qcol[i]];
    geo.evaluate(q, xyz);
    d += f ? ",[" : "[";
    for (std::size_t i = 0; i < xyz.size(); ++i) {
      for (int k = 0; k < 3; ++k) {
        if (i || k) d += ',';
        number(d, xyz[i](k));
      }
    }
    d += ']';
  }
  // Every column but t and q (they are drawn) for the plots.
  d += "],\"columns\":{";
  bool first = true;
  for (std::size_t c = 1; c < tab.header.size(); ++c) {
    if (std::find(qcol.begin(), qcol.end(), c) != qcol.end()) continue;
    d += (first ? "" : ",") + js_string(tab.header[c]) + ":[";
    first = false;
    for (std::size_t f = 0; f < tab.rows.size(); ++f) {
      if (f) d += ',';
      number(d, tab.rows[f][c]);
    }
    d += ']';
  }
  // The plots shown at first: position residuals, constraint forces, energy.
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
  d += "},\"groups\":{";
  d += group("position residuals Φ [m or rad]",
             [](const std::string& h) { return h.rfind("res_", 0) == 0; });
  d += "," + group("constraint force Qc [N or N·m]",
                   [](const std::string& h) { return h.rfind("Qc_", 0) == 0; });
  d += "," + group("energy [J]", [](const std::string& h) {
         return h == "T" || h == "V" || h == "E" || h == "E_balance";
       });
  d += "}}";

  const std::string importmap =
      "{\"imports\":{\"three\":\"data:text/javascript;base64," + base64(replay_assets::three_js) +
      "\",\"three/addons/controls/OrbitControls.js\":\"data:text/javascript;base64," +
      base64(replay_assets::orbit_controls_js) + "\"}}";
  // The template's placeholders are found in the template itself, so nothing a value holds can be
  // taken for one.
  const std::string title = html_escape(sc.name);
  const std::vector<std::pair<std::string_view, std::string_view>> values{
      {"@TITLE@", title},
      {"@DATA@", d},
      {"@IMPORTMAP@", importmap},
      {"@APP@", replay_assets::app_js}};
  const std::string_view tpl = replay_assets::page_html;
  std::string page;
  page.reserve(tpl.size() + d.size() + importmap.size() + replay_assets::app_js.size());
  std::size_t pos = 0, filled = 0;
  while (pos < tpl.size()) {
    std::size_t next = std::string_view::npos;
    const std::pair<std::string_view, std::string_view>* which = nullptr;
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

  OutputDir out(out_dir);
  out.require_file_or_absent(out.fd(), "", kReplayFile);
  AtomicFile f(out, out.fd(), "", kReplayFile);
  f.write(page);
  f.commit();
  out.sync();
  res.file = out_dir / kReplayFile;
  res.bytes = page.size();
  return res;
}

}  // namespace ukdyn
