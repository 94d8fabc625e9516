// Every YAML example of the docs (README.md, docs/*.md) is true: a ```yaml block that is a whole
// file (a scenario `ukdyn: 1`, an optimisation problem, a sweep, a sizing file, a catalogue) loads
// with ukdyn's own loaders, and a hostile case (first line `# expect: MESSAGE`) is refused with its
// message. A block that is a fragment says so on the line before it, with the reason:
// `<!-- fragment: REASON -->`; an unmarked block that is no whole file fails here. A whole file
// that names others relative to itself (`base: ../paper.yaml`) is written into a copy of
// scenarios/ and robots/, in the folder `<!-- file: FOLDER -->` gives (default by kind: scenarios/,
// scenarios/optimize/, scenarios/sweeps/, scenarios/sizing/). docs/README.md, "Contributor notes",
// documents the markers.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "cli_run.hpp"
#include "ukdyn/scenario/optimization_file.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/sweep/sizing.hpp"
#include "ukdyn/sweep/sweep.hpp"

namespace {

namespace fs = std::filesystem;
const fs::path kSource = UKDYN_SOURCE_DIR;

struct Block {
  fs::path doc;
  int line = 0;          // of the opening fence, from 1
  std::string lang;      // yaml, sh, ...
  std::string text;      // between the fences
  std::string fragment;  // the reason of a `<!-- fragment: ... -->` marker, empty if none
  bool marked = false;   // a fragment marker stands before the block
  std::string folder;    // of a `<!-- file: ... -->` marker
};

std::vector<fs::path> doc_files() {
  std::vector<fs::path> docs{kSource / "README.md"};
  for (const auto& e : fs::directory_iterator(kSource / "docs"))
    if (e.path().extension() == ".md") docs.push_back(e.path());
  std::sort(docs.begin(), docs.end());
  return docs;
}

// The fenced blocks of one Markdown file, with the marker on the last non-blank line before each.
std::vector<Block> fenced_blocks(const fs::path& doc) {
  std::ifstream in(doc);
  std::vector<std::string> lines;
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  static const std::regex fragment_re(R"(^\s*<!--\s*fragment:\s*(.*?)\s*-->\s*$)");
  static const std::regex file_re(R"(^\s*<!--\s*file:\s*(\S+)\s*-->\s*$)");
  std::vector<Block> out;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    if (lines[i].rfind("```", 0) != 0) continue;
    Block b{doc, static_cast<int>(i + 1), lines[i].substr(3), {}, {}, false, {}};
    std::size_t p = i;
    while (p > 0 && lines[p - 1].find_first_not_of(" \t") == std::string::npos) --p;
    std::smatch m;
    if (p > 0 && std::regex_match(lines[p - 1], m, fragment_re)) {
      b.marked = true;
      b.fragment = m[1];
    } else if (p > 0 && std::regex_match(lines[p - 1], m, file_re)) {
      b.folder = m[1];
    }
    std::size_t j = i + 1;
    for (; j < lines.size() && lines[j].rfind("```", 0) != 0; ++j) b.text += lines[j] + "\n";
    out.push_back(b);
    i = j;
  }
  return out;
}

std::string first_line(const std::string& text) { return text.substr(0, text.find('\n')); }

// What a whole file is, by its first line: "" when it is none of them.
std::string kind_of(const std::string& text) {
  const std::string l = first_line(text);
  if (l.rfind("# expect:", 0) == 0) return "hostile";
  for (const char* k : {"ukdyn_sweep:", "ukdyn_sizing:", "ukdyn_catalogue:"})
    if (l.rfind(k, 0) == 0) return std::string(k).substr(6, std::string(k).size() - 7);
  if (l.rfind("ukdyn:", 0) == 0)
    return text.find("\nscenario:") != std::string::npos ? "optimization" : "scenario";
  return "";
}

std::string where(const Block& b) {
  return fs::relative(b.doc, kSource).string() + ":" + std::to_string(b.line);
}

// A copy of scenarios/ and robots/ for the whole files to sit in (their relative names resolve).
const fs::path& tree() {
  static const ukdyn_test::ScratchDir dir("ukdyn_doc_examples");  // tests only: one per process
  static const bool copied = [] {
    for (const char* d : {"scenarios", "robots"})
      fs::copy(kSource / d, dir.path / d, fs::copy_options::recursive);
    return true;
  }();
  (void)copied;
  return dir.path;
}

// Loads a whole file as what it is; throws what the loader throws.
void load_whole_file(const Block& b, const std::string& kind) {
  static const std::map<std::string, std::string> default_folder{
      {"scenario", "scenarios"},
      {"hostile", "scenarios"},
      {"optimization", "scenarios/optimize"},
      {"sweep", "scenarios/sweeps"},
      {"sizing", "scenarios/sizing"},
      {"catalogue", "scenarios/sizing"}};
  const fs::path dir = tree() / (b.folder.empty() ? default_folder.at(kind) : b.folder);
  fs::create_directories(dir);
  const fs::path file =
      dir / ("doc_" + b.doc.stem().string() + "_" + std::to_string(b.line) + ".yaml");
  std::ofstream(file, std::ios::binary) << b.text;
  if (kind == "scenario" || kind == "hostile") {
    (void)ukdyn::load_scenario_file(file);
  } else if (kind == "optimization") {
    (void)ukdyn::load_optimization_file(file);
  } else if (kind == "sweep") {
    const ukdyn::Sweep s = ukdyn::load_sweep(file);
    // The base with sample 0's numbers written in is a scenario that loads.
    (void)ukdyn::load_scenario_text(ukdyn::sample_scenario_text(s, 0), file);
  } else if (kind == "sizing") {
    (void)ukdyn::load_sizing_file(file);
  } else {
    (void)ukdyn::load_catalogue(file);
  }
}

TEST(DocExamples, EveryYamlBlockIsAWholeFileOrAMarkedFragment) {
  int yaml_blocks = 0;
  for (const fs::path& doc : doc_files()) {
    for (const Block& b : fenced_blocks(doc)) {
      if (b.lang != "yaml") continue;
      ++yaml_blocks;
      const std::string kind = kind_of(b.text);
      if (b.marked) {
        EXPECT_FALSE(b.fragment.empty()) << where(b) << ": a fragment marker needs its reason";
        EXPECT_TRUE(kind.empty() || kind == "hostile")
            << where(b) << ": marked a fragment but is a whole " << kind << " file";
      } else {
        EXPECT_FALSE(kind.empty())
            << where(b) << ": neither a whole file (first line `ukdyn: 1`, "
            << "`ukdyn_sweep: 1`, ...) nor marked `<!-- fragment: REASON -->`"
            << " on the line before it";
      }
    }
  }
  EXPECT_GE(yaml_blocks, 20) << "the docs' YAML blocks were not found";
}

TEST(DocExamples, EveryWholeFileLoads) {
  int loaded = 0, refused = 0;
  for (const fs::path& doc : doc_files()) {
    for (const Block& b : fenced_blocks(doc)) {
      const std::string kind = b.lang == "yaml" && !b.marked ? kind_of(b.text) : "";
      if (kind.empty()) continue;
      if (kind == "hostile") {
        const std::string expect = first_line(b.text).substr(std::string("# expect:").size() + 1);
        try {
          load_whole_file(b, kind);
          ADD_FAILURE() << where(b) << ": loaded, expected the error '" << expect << "'";
        } catch (const std::exception& e) {
          EXPECT_NE(std::string(e.what()).find(expect), std::string::npos)
              << where(b) << ": '" << e.what() << "' lacks '" << expect << "'";
          ++refused;
        }
        continue;
      }
      try {
        load_whole_file(b, kind);
        ++loaded;
      } catch (const std::exception& e) {
        ADD_FAILURE() << where(b) << " (" << kind << " file): " << e.what();
      }
    }
  }
  // Today: the annotated scenario of scenario-format.md, the sweep, the sizing file and its
  // catalogue; a block lost (a broken fence) shows here.
  EXPECT_GE(loaded + refused, 4);
}

// The scenario, robot and test model files the docs name in backticks exist (a renamed file leaves
// its name in a page). A name with a word N is a pattern (`scenarios/n_robots_N_weld.yaml`); a
// page that tells the reader to write a file says so: `<!-- to write: NAME -->`.
TEST(DocExamples, NamedScenarioAndRobotFilesExist) {
  static const std::regex name_re(
      R"(`((scenarios|robots|tests)/[A-Za-z0-9_./-]+\.(yaml|urdf|xml))`)");
  static const std::regex pattern_re(R"([/_]N[_.])");
  static const std::regex to_write_re(R"(<!--\s*to write:\s*(\S+)\s*-->)");
  int named = 0;
  for (const fs::path& doc : doc_files()) {
    std::ifstream in(doc);
    std::vector<std::string> lines;
    std::set<std::string> to_write;
    for (std::string l; std::getline(in, l);) {
      lines.push_back(l);
      std::smatch m;
      if (std::regex_search(l, m, to_write_re)) to_write.insert(m[1]);
    }
    int line = 0;
    for (const std::string& l : lines) {
      ++line;
      for (std::sregex_iterator it(l.begin(), l.end(), name_re), end; it != end; ++it) {
        if (std::regex_search((*it)[1].str(), pattern_re) || to_write.count((*it)[1])) continue;
        ++named;
        EXPECT_TRUE(fs::exists(kSource / (*it)[1].str()))
            << fs::relative(doc, kSource).string() << ":" << line << ": names " << (*it)[1]
            << ", which does not exist";
      }
    }
  }
  EXPECT_GE(named, 20);
}

#ifdef UKDYN_TEST_HAVE_CLI
// Every `ukdyn SUBCOMMAND ... --option` the pages write (in code blocks and in backticks) names a
// subcommand that exists and options its `--help` lists.
TEST(DocExamplesCli, CommandLinesUseOptionsTheHelpLists) {
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_doc_examples_cli");
  const std::string subs[] = {"simulate",  "replay",        "assemble", "eval",
                              "linearize", "sensitivities", "check",    "derive",
                              "sweep",     "optimize",      "size"};
  std::map<std::string, std::string> help;
  for (const std::string& s : subs) {
    const auto r = ukdyn_test::run_cli(UKDYN_CLI, scratch, s + " --help");
    ASSERT_EQ(r.exit_code, 0) << s << ": " << r.err;
    help[s] = r.out;
  }
  help["sweep"] += ukdyn_test::run_cli(UKDYN_CLI, scratch, "sweep merge --help").out;
  static const std::regex command_re(
      R"(ukdyn (simulate|replay|assemble|eval|linearize|sensitivities|check|derive|sweep|optimize|size)\b([^`|;#]*))");
  static const std::regex option_re(R"((?:^|\s)(--[a-z][a-z-]*|-[a-zA-Z])(?=[\s=]|$))");
  std::vector<fs::path> pages = doc_files();
  pages.push_back(kSource / "robots" / "README.md");
  int options = 0;
  for (const fs::path& doc : pages) {
    std::ifstream in(doc);
    int line = 0;
    for (std::string l; std::getline(in, l);) {
      ++line;
      for (std::sregex_iterator it(l.begin(), l.end(), command_re), end; it != end; ++it) {
        const std::string sub = (*it)[1], rest = (*it)[2];
        for (std::sregex_iterator o(rest.begin(), rest.end(), option_re); o != end; ++o) {
          const std::string opt = (*o)[1];
          ++options;
          // "-o," / "--out " as --help prints them
          const bool listed =
              std::regex_search(help[sub], std::regex("(^|[\\s,])" + opt + "([\\s,=]|$)"));
          EXPECT_TRUE(listed) << fs::relative(doc, kSource).string() << ":" << line << ": ukdyn "
                              << sub << " " << opt << " is not in `ukdyn " << sub << " --help`";
        }
      }
    }
  }
  EXPECT_GE(options, 30);
}
#endif

}  // namespace
