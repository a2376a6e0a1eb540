// Scratch files for tests: one folder per test process under the system
// temporary folder, made on first use and removed when the process exits, so
// that test processes running side by side never share a file and a test run
// leaves nothing behind.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <string>
#include <system_error>

namespace brdfkit::test {

// This process's scratch folder.
inline const std::filesystem::path& ProcessDir() {
  struct Owned {
    std::filesystem::path path;
    pid_t owner;
    Owned()
        : path(std::filesystem::temp_directory_path() / ("brdfkit-test-" + std::to_string(::getpid()))),
          owner(::getpid()) {
      std::filesystem::remove_all(path);
      std::filesystem::create_directories(path);
    }
    ~Owned() {
      std::error_code ec;
      // A forked child that exits normally must not remove its parent's files.
      if (::getpid() == owner) std::filesystem::remove_all(path, ec);
    }
  };
  static const Owned dir;
  return dir.path;
}

// A path for a scratch file of this process (the file is not created).
inline std::filesystem::path ScratchPath(const std::string& name) { return ProcessDir() / name; }

// A fresh empty folder in this process's scratch folder.
inline std::filesystem::path FreshDir(const std::string& name) {
  const auto d = ProcessDir() / name;
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

}  // namespace brdfkit::test
