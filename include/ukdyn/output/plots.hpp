// Figures (PNG) from a run's CSV, drawn by gnuplot (Debian gnuplot-nox, pngcairo terminal).
// gnuplot is started directly (no shell), in a fresh private folder, from a script in which every
// string is a quoted literal (gnuplot_string); the PNGs it draws are then renamed into
// OUT/figures. ukdyn touches in OUT/figures only the files it lists in OUT/figures/.ukdyn-figures
// (the PNGs, figures.gp, gnuplot.log of its last run), never anything else there.
#pragma once

#include <atomic>
#include <string>
#include <utility>
#include <vector>

#include "ukdyn/output/output_dir.hpp"

namespace ukdyn {

struct Figure {
  std::string file;  ///< e.g. "residuals_closure.png" (made a safe, unique file name on drawing)
  std::string title;
  std::string ylabel;
  std::vector<std::string> columns;  ///< CSV column names, plotted against t
  /// An operating-point figure instead of curves against t: |column| against |x_column| for every
  /// sample, as points, drawn from the whole CSV (never the decimated copy, whose per-column
  /// extremes would pair values of different samples); and curves y = f(x) given as gnuplot
  /// expressions that ukdyn writes from numbers only (e.g. a motor's envelope), with their titles.
  std::string x_column{};
  std::string xlabel{};
  std::vector<std::pair<std::string, std::string>> functions{};
  double x_max{0.0};  ///< > 0: the x axis of an operating-point figure at least up to x_max
};

/// At most this many figures per run, and this many curves per figure.
inline constexpr std::size_t kMaxFigures = 40;
inline constexpr std::size_t kMaxSeriesPerFigure = 12;

/// Cuts `figures` to the limits above; says what was left out in `notes` (one line each).
void cap_figures(std::vector<Figure>& figures, std::vector<std::string>& notes);

/// A run of more rows than this is drawn from a decimated copy (OUT/figures/figures_data.csv):
/// per column the minimum and maximum of each of kFigureBuckets runs of consecutive samples, so
/// every extreme of every curve is kept (the figures are 1000 pixels wide).
inline constexpr std::size_t kDecimateAbove = 4000;
inline constexpr std::size_t kFigureBuckets = 2000;

struct FigureResult {
  std::vector<std::string> written;  ///< relative to OUT, e.g. "figures/energy.png"
  std::string error;                 ///< empty if gnuplot drew everything
  std::string note;                  ///< drawn from a decimated copy: how (else empty)
};

/// Draws the figures from OUT/<csv_name> into OUT/figures, with the gnuplot script beside them
/// (figures.gp: `cd OUT/figures && gnuplot figures.gp` redraws them). gnuplot is stopped if
/// `cancel` becomes true or after 300 s. Failures go to FigureResult.error (the run's data is not
/// affected); throws OutputRefused only if OUT/figures or one of its names is not ukdyn's.
FigureResult render_figures(const OutputDir& out, const std::string& csv_name,
                            const std::vector<std::string>& header,
                            const std::vector<Figure>& figures,
                            const std::atomic<bool>* cancel = nullptr);

/// Removes the figures (and script, log) that the last run listed in OUT/figures/.ukdyn-figures,
/// and that list. Only regular files under names ukdyn makes are removed; nothing else is touched.
void remove_previous_figures(const OutputDir& out);

}  // namespace ukdyn

namespace ukdyn {

/// Runs a gnuplot script (every string in it a gnuplot_string literal; data read as "../NAME",
/// i.e. from OUT) that draws the PNGs `files`, and moves them into OUT/figures as render_figures()
/// does (listed in OUT/figures/.ukdyn-figures; the script kept as figures.gp). Used by sweeps.
FigureResult render_gnuplot_script(const OutputDir& out, const std::string& script,
                                   const std::vector<std::string>& files,
                                   const std::atomic<bool>* cancel = nullptr);

}  // namespace ukdyn
