#include "python/src/common.h"

#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/task_arena.h>

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <thread>

namespace brdfkit::python {

bool IsFloat32(const py::handle& obj) {
  return py::isinstance<py::array>(obj) && py::reinterpret_borrow<py::array>(obj).dtype().is(py::dtype::of<float>());
}

namespace {

std::string ShapeText(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

}  // namespace

template <typename T>
Rows<T> AsRowsUnchecked(const py::handle& obj, const char* name, int width) {
  py::array raw = py::array::ensure(obj);
  if (!raw) throw DtypeError(std::string(name) + " must be an array of numbers");
  const char kind = raw.dtype().kind();
  if (kind != 'f' && kind != 'i' && kind != 'u')
    throw DtypeError(std::string(name) + " must hold real numbers (got dtype " +
                     py::str(py::object(raw.dtype())).cast<std::string>() + ")");
  Rows<T> r;
  const std::string want = "(N, " + std::to_string(width) + ") or (" + std::to_string(width) + ",)";
  if (raw.ndim() == 1 && raw.shape(0) == width) {
    r.single = true;
    r.n = 1;
    r.stride = 0;
  } else if (raw.ndim() == 2 && raw.shape(1) == width) {
    r.n = static_cast<std::size_t>(raw.shape(0));
    r.stride = width;
  } else {
    throw ArgumentError(std::string(name) + " must have shape " + want + ", got " + ShapeText(raw));
  }
  r.array = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(raw);
  if (!r.array) throw DtypeError(std::string(name) + ": cannot convert to " + (kIsFloat<T> ? "float32" : "float64"));
  return r;
}

// The tolerance on |row|^2 - 1 of a unit direction: 2e-5 covers float32
// rounding of a normalised vector (about 1e-7) with room to spare.
constexpr double kUnitTolerance = 2e-5;

template <typename T>
void CheckRows(const Rows<T>& r, const char* name, int width, bool unit) {
  const T* d = r.array.data();
  const std::size_t rows = r.single ? 1 : r.n;
  for (std::size_t k = 0; k < rows; ++k) {
    double norm2 = 0;
    for (int c = 0; c < width; ++c) {
      const double v = d[k * width + c];
      if (!std::isfinite(v))
        throw ArgumentError(std::string(name) + (r.single ? "" : " row " + std::to_string(k)) +
                            " is not finite (value " + FormatDouble(v) + ")");
      norm2 += v * v;
    }
    if (unit && std::abs(norm2 - 1.0) > kUnitTolerance)
      throw ArgumentError(std::string(name) + (r.single ? "" : " row " + std::to_string(k)) +
                          " is not a unit vector (length " + FormatDouble(std::sqrt(norm2)) + ")");
  }
}

template <typename T>
bool UnitRows(const T* d, std::size_t rows) {
  // One test per row, as CheckRows's: a non-finite component makes norm2
  // infinite or NaN, which fails the comparison. Written without branches
  // so that the loop vectorises.
  bool ok = true;
  for (std::size_t k = 0; k < rows; ++k) {
    const double x = d[3 * k], y = d[3 * k + 1], z = d[3 * k + 2];
    const double norm2 = x * x + y * y + z * z;
    ok &= std::abs(norm2 - 1.0) <= kUnitTolerance;
  }
  return ok;
}

template <typename T>
Rows<T> AsRows(const py::handle& obj, const char* name, int width, bool unit) {
  Rows<T> r = AsRowsUnchecked<T>(obj, name, width);
  CheckRows(r, name, width, unit);
  return r;
}

template Rows<double> AsRows<double>(const py::handle&, const char*, int, bool);
template Rows<float> AsRows<float>(const py::handle&, const char*, int, bool);
template Rows<double> AsRowsUnchecked<double>(const py::handle&, const char*, int);
template Rows<float> AsRowsUnchecked<float>(const py::handle&, const char*, int);
template void CheckRows<double>(const Rows<double>&, const char*, int, bool);
template void CheckRows<float>(const Rows<float>&, const char*, int, bool);
template bool UnitRows<double>(const double*, std::size_t);
template bool UnitRows<float>(const float*, std::size_t);

std::size_t BroadcastRows(const char* a, std::size_t na, bool single_a, const char* b, std::size_t nb, bool single_b) {
  if (single_a) return nb;
  if (single_b || na == nb) return na;
  throw ArgumentError(std::string(a) + " has " + std::to_string(na) + " rows and " + b + " has " +
                      std::to_string(nb) + ": give the same number, or one direction for all");
}

template <typename T>
py::array_t<T> NewRows(std::size_t n, int width, bool single) {
  if (single) return py::array_t<T>(std::vector<py::ssize_t>{width});
  return py::array_t<T>(std::vector<py::ssize_t>{static_cast<py::ssize_t>(n), width});
}

template py::array_t<double> NewRows<double>(std::size_t, int, bool);
template py::array_t<float> NewRows<float>(std::size_t, int, bool);

py::object ToPython(const nlohmann::json& j) {
  switch (j.type()) {
    case nlohmann::json::value_t::null:
      return py::none();
    case nlohmann::json::value_t::boolean:
      return py::bool_(j.get<bool>());
    case nlohmann::json::value_t::number_integer:
      return py::int_(j.get<std::int64_t>());
    case nlohmann::json::value_t::number_unsigned:
      return py::int_(j.get<std::uint64_t>());
    case nlohmann::json::value_t::number_float:
      return py::float_(j.get<double>());
    case nlohmann::json::value_t::string:
      return py::str(j.get<std::string>());
    case nlohmann::json::value_t::array: {
      py::list l;
      for (const auto& e : j) l.append(ToPython(e));
      return l;
    }
    case nlohmann::json::value_t::object: {
      py::dict d;
      for (const auto& [k, v] : j.items()) d[py::str(k)] = ToPython(v);
      return d;
    }
    default:
      return py::none();
  }
}

void RunReleased(int threads, const std::function<void(const CancelToken&)>& work) {
  CancelToken token;
  std::exception_ptr error;
  std::mutex mutex;
  std::condition_variable cv;
  bool done = false, interrupted = false;
  const int n = threads > 0 ? threads : tbb::info::default_concurrency();
  {
    py::gil_scoped_release release;
    std::thread worker([&] {
      try {
        tbb::task_arena arena(n);
        arena.execute([&] { work(token); });
      } catch (...) {
        error = std::current_exception();
      }
      std::lock_guard<std::mutex> lock(mutex);
      done = true;
      cv.notify_all();
    });
    std::unique_lock<std::mutex> lock(mutex);
    while (!done) {
      if (cv.wait_for(lock, std::chrono::milliseconds(50), [&] { return done; })) break;
      if (interrupted) continue;
      lock.unlock();
      {
        py::gil_scoped_acquire gil;
        // Sets KeyboardInterrupt (or the handler's exception) on Ctrl-C.
        if (PyErr_CheckSignals() != 0) interrupted = true;
      }
      if (interrupted) token.Cancel();
      lock.lock();
    }
    lock.unlock();
    worker.join();
  }
  if (interrupted) throw py::error_already_set();
  if (error) std::rethrow_exception(error);
}

}  // namespace brdfkit::python
