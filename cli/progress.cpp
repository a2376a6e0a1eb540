#include "cli/progress.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <cstdio>

namespace brdfkit::cli {

namespace {

std::atomic<int> g_interrupts{0};

extern "C" void OnInterrupt(int) {
  // Second Ctrl-C: the user wants out now; the default action ends the process.
  if (g_interrupts.fetch_add(1) >= 1) {
    std::signal(SIGINT, SIG_DFL);
    std::raise(SIGINT);
  }
}

std::string Clock(double seconds) {
  char buf[32];
  const long s = static_cast<long>(seconds + 0.5);
  if (s >= 3600) std::snprintf(buf, sizeof buf, "%ld:%02ld:%02ld", s / 3600, (s / 60) % 60, s % 60);
  else std::snprintf(buf, sizeof buf, "%ld:%02ld", s / 60, s % 60);
  return buf;
}

}  // namespace

void InstallInterruptHandler() {
  struct sigaction sa {};
  sa.sa_handler = OnInterrupt;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
}

bool InterruptRequested() { return g_interrupts.load() > 0; }

void ThrowIfInterrupted() {
  if (InterruptRequested()) throw Interrupted();
}

Progress::Progress(std::string label, double total, bool quiet)
    : label_(std::move(label)), total_(total), enabled_(!quiet && isatty(STDERR_FILENO) == 1) {
  start_ = last_ = std::chrono::steady_clock::now();
}

Progress::~Progress() { Finish(); }

void Progress::Update(double done, const std::string& note) {
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  // Short work shows nothing; redraws are limited to ten a second.
  if (elapsed < 1.0 || std::chrono::duration<double>(now - last_).count() < 0.1) return;
  last_ = now;
  Draw(done, note, false);
}

void Progress::Finish() {
  if (!enabled_ || !drawn_) return;
  std::fprintf(stderr, "\r\033[K");
  std::fflush(stderr);
  drawn_ = false;
}

void Progress::Draw(double done, const std::string& note, bool) {
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  std::string line = label_ + " ";
  if (total_ > 0) {
    const double f = std::min(1.0, std::max(0.0, done / total_));
    constexpr int kWidth = 28;
    const int filled = static_cast<int>(f * kWidth);
    line += "[" + std::string(filled, '#') + std::string(kWidth - filled, '-') + "] ";
    char buf[96];
    if (f > 0) std::snprintf(buf, sizeof buf, "%3.0f%% %s elapsed, %s left", 100 * f, Clock(elapsed).c_str(),
                             Clock(elapsed * (1 - f) / f).c_str());
    else std::snprintf(buf, sizeof buf, "  0%% %s elapsed", Clock(elapsed).c_str());
    line += buf;
  } else {
    line += Clock(elapsed) + " elapsed";
  }
  if (!note.empty()) line += "  " + note;
  std::fprintf(stderr, "\r\033[K%s", line.c_str());
  std::fflush(stderr);
  drawn_ = true;
}

std::function<void(std::size_t, std::size_t)> ThreadedProgress::Callback() {
  return [this](std::size_t done, std::size_t total) {
    ThrowIfInterrupted();
    std::unique_lock<std::mutex> lock(mutex_, std::try_to_lock);
    if (!lock.owns_lock()) return;  // another thread is drawing
    if (!bar_) bar_ = std::make_unique<Progress>(label_, double(total), quiet_);
    bar_->Update(double(done));
  };
}

void ThreadedProgress::Finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (bar_) bar_->Finish();
}

}  // namespace brdfkit::cli
