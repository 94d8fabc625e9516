// Figures (PNG) from a run's CSV, drawn by gnuplot (Debian gnuplot-nox, pngcairo terminal).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace ukdyn {

struct Figure {
  std::string file;  ///< e.g. "residuals_closure.png"
  std::string title;
  std::string ylabel;
  std::vector<std::string> columns;  ///< CSV column names, plotted against t
};

/// Writes each figure into fig_dir (with the gnuplot script beside it, figures.gp, so a user can
/// restyle them). Returns the PNGs written. On failure (no gnuplot), returns what was written and
/// sets `error`; the run's data is not affected.
std::vector<std::filesystem::path> render_figures(const std::filesystem::path& csv,
                                                  const std::vector<std::string>& header,
                                                  const std::vector<Figure>& figures,
                                                  const std::filesystem::path& fig_dir,
                                                  std::string& error);

}  // namespace ukdyn
