// The tests' scratch folder (tests/scratch.h): one per process, gone when the
// process exits, kept when a forked child exits.
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>

#include <gtest/gtest.h>

#include "tests/cli_util.h"
#include "tests/scratch.h"

namespace brdfkit::test {
namespace {

namespace fs = std::filesystem;

TEST(Scratch, TheProcessFolderIsRemovedWhenTheProcessExits) {
  if (std::getenv("BRDFKIT_SCRATCH_CHILD")) {
    // The child's part: leave a file and a folder behind, say where.
    std::ofstream(ScratchPath("left.txt")) << "x";
    std::ofstream(FreshDir("sub") / "deeper.txt") << "y";
    std::cout << "scratch=" << ProcessDir().string() << std::endl;
    return;
  }
  // This test program run again for this test alone, unsharded.
  const std::string self = fs::read_symlink("/proc/self/exe").string();
  const CliRun r = Shell("env -u GTEST_TOTAL_SHARDS -u GTEST_SHARD_INDEX BRDFKIT_SCRATCH_CHILD=1 " + self +
                         " --gtest_filter=Scratch.TheProcessFolderIsRemovedWhenTheProcessExits");
  ASSERT_EQ(r.code, 0) << r.out;
  const auto at = r.out.find("scratch=");
  ASSERT_NE(at, std::string::npos) << r.out;
  const fs::path child(r.out.substr(at + 8, r.out.find('\n', at) - at - 8));
  EXPECT_NE(child, ProcessDir());
  EXPECT_EQ(child.parent_path(), fs::temp_directory_path());
  EXPECT_FALSE(fs::exists(child)) << child;

  // A forked child that exits normally leaves its parent's folder alone.
  std::ofstream(ScratchPath("mine.txt")) << "z";
  std::cout.flush();
  std::fflush(nullptr);
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) std::exit(0);
  int status = 0;
  ::waitpid(pid, &status, 0);
  EXPECT_TRUE(fs::exists(ScratchPath("mine.txt")));
}

}  // namespace
}  // namespace brdfkit::test
