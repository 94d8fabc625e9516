// ukdyn.size (docs/sizing.md, docs/python.md "Sizing actuators"): the smallest catalogue motor +
// gearbox per actuator, the result as the dict of sizing.json.
#include <pybind11/stl.h>

#include <optional>
#include <string>

#include "bindings.hpp"
#include "ukdyn/sweep/sizing.hpp"

namespace ukdyn_python {

namespace {

// Runs with the GIL released (the runs are C++ only); with `out`, also sizing.json and
// candidates.csv there.
py::object size(const std::string& path, const std::optional<std::string>& out) {
  const ukdyn::SizingFile f = ukdyn::load_sizing_file(path);
  ukdyn::SizingResult r;
  {
    py::gil_scoped_release release;
    r = ukdyn::run_sizing(f);
    if (out) ukdyn::write_sizing(f, r, *out);
  }
  return py::module_::import("json").attr("loads")(ukdyn::sizing_json(f, r));
}

}  // namespace

void bind_size(py::module_& m) {
  m.def("size", &size, py::arg("path"), py::arg("out") = std::nullopt,
        "Sizes the actuators of a sizing file (docs/sizing.md): per actuator the smallest "
        "catalogue motor + gearbox that keeps the margin at every operating point of every "
        "sample; returns the contents of sizing.json as a dict; with out, also writes "
        "sizing.json and candidates.csv there");
}

}  // namespace ukdyn_python
