// Progress bars on stderr and a clean stop on Ctrl-C.
//
// A bar appears only when stderr is a terminal, --quiet is not given, and
// the work has run for more than a second; it shows the fraction done and
// the estimated time left (elapsed x (1 - f) / f). Work of unknown length
// shows its elapsed time and a count.
//
// Ctrl-C sets a flag; long work calls ThrowIfInterrupted() between units,
// which throws Interrupted. Outputs are written to temporary names and
// renamed when complete, so unwinding leaves no half-written file. A second
// Ctrl-C ends the process at once.
#pragma once

#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>

namespace brdfkit::cli {

class Interrupted : public std::runtime_error {
 public:
  Interrupted() : std::runtime_error("interrupted (Ctrl-C)") {}
};

void InstallInterruptHandler();
bool InterruptRequested();
void ThrowIfInterrupted();

class Progress {
 public:
  // total <= 0: unknown length.
  Progress(std::string label, double total, bool quiet);
  ~Progress();
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  void Update(double done, const std::string& note = "");
  void Finish();

 private:
  void Draw(double done, const std::string& note, bool final_line);
  std::string label_;
  double total_;
  bool enabled_;
  bool drawn_ = false;
  std::chrono::steady_clock::time_point start_, last_;
};

// A Progress fed from worker threads: the callback checks for Ctrl-C
// (throwing Interrupted, which stops a TBB loop and propagates) and draws
// from whichever thread holds the lock.
class ThreadedProgress {
 public:
  ThreadedProgress(std::string label, bool quiet) : label_(std::move(label)), quiet_(quiet) {}
  std::function<void(std::size_t, std::size_t)> Callback();
  void Finish();

 private:
  std::string label_;
  bool quiet_;
  std::mutex mutex_;
  std::unique_ptr<Progress> bar_;
};

}  // namespace brdfkit::cli
