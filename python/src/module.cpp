// The compiled part of the Python package: brdfkit._brdfkit.
#include "cli/common.h"
#include "python/src/callable.h"
#include "python/src/common.h"

namespace py = pybind11;
using namespace brdfkit;

PYBIND11_MODULE(_brdfkit, m) {
  m.doc() = "Compiled core of the brdfkit package (models, checks, albedo tables, measurements, fits, files).";
  // User errors carry the command line's messages.
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const python::DtypeError& e) {
      PyErr_SetString(PyExc_TypeError, e.what());
    } catch (const python::Cancelled&) {
      PyErr_SetNone(PyExc_KeyboardInterrupt);
    } catch (const std::invalid_argument& e) {  // ArgumentError, bad option values
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const ModelError& e) {  // unknown model or parameter, out of range, bad model file
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const cli::UsageError& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const std::runtime_error& e) {  // bad data files, named with their line
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });
  python::BindModels(m);
  python::BindCallables(m);
  python::BindTools(m);
}
