// Whole-file output that never leaves a truncated file behind: data goes to
// a temporary name beside the target and is renamed over it only when
// complete. A failure (or an exception before Commit) removes the temporary.
#pragma once

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>
#include <string>

namespace brdfkit {

class AtomicFile {
 public:
  explicit AtomicFile(const std::filesystem::path& target, std::ios::openmode mode = std::ios::out)
      : target_(target) {
    namespace fs = std::filesystem;
    if (fs::is_directory(target_))
      throw std::runtime_error("cannot write '" + target_.string() + "': it is a directory");
    std::random_device rd;
    tmp_ = target_;
    tmp_ += ".tmp-" + std::to_string(rd() % 1000000);
    out_.open(tmp_, mode | std::ios::trunc);
    if (!out_) throw std::runtime_error("cannot write '" + target_.string() + "' (cannot create a file there)");
  }
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  ~AtomicFile() {
    if (!committed_) {
      out_.close();
      std::error_code ec;
      std::filesystem::remove(tmp_, ec);
    }
  }

  std::ofstream& stream() { return out_; }

  void Commit() {
    out_.flush();
    if (!out_) throw std::runtime_error("writing '" + target_.string() + "' failed");
    out_.close();
    std::error_code ec;
    std::filesystem::rename(tmp_, target_, ec);
    if (ec) throw std::runtime_error("cannot write '" + target_.string() + "': " + ec.message());
    committed_ = true;
  }

  const std::filesystem::path& temp_path() const { return tmp_; }

 private:
  std::filesystem::path target_, tmp_;
  std::ofstream out_;
  bool committed_ = false;
};

inline void WriteFileAtomic(const std::filesystem::path& target, const std::string& content) {
  AtomicFile f(target, std::ios::out | std::ios::binary);
  f.stream() << content;
  f.Commit();
}

}  // namespace brdfkit
