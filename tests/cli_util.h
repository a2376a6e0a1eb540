// Running the built command-line tool from tests: exit code and output.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "tests/scratch.h"

namespace brdfkit::test {

struct CliRun {
  int code;
  std::string out;  // stdout and stderr
};

// Runs a shell command line, stdout and stderr together.
inline CliRun Shell(const std::string& command) {
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  CliRun r{-1, ""};
  if (!pipe) return r;
  std::array<char, 4096> buf;
  std::size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) r.out.append(buf.data(), n);
  const int status = pclose(pipe);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

// Runs `brdfkit ARGS` through the shell; `pre` may prefix it ("cd DIR && ").
inline CliRun Brdfkit(const std::string& args, const std::string& pre = "") {
  return Shell(pre + std::string(BRDFKIT_EXE) + " " + args);
}

inline std::string ReadText(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

inline void WriteText(const std::filesystem::path& p, const std::string& text) {
  std::ofstream out(p, std::ios::binary);
  out << text;
}

}  // namespace brdfkit::test
