// The README's table of registered models is the output of
// `brdfkit models --markdown`, generated from every model's Info(): the
// test fails when one of them changes without the other.
#include <gtest/gtest.h>

#include <string>

#include "tests/cli_util.h"

namespace brdfkit {
namespace {

TEST(ModelsTable, ReadmeTableIsTheGeneratedOne) {
  const test::CliRun r = test::Brdfkit("models --markdown");
  ASSERT_EQ(r.code, 0) << r.out;
  ASSERT_EQ(r.out.rfind("| model |", 0), 0u) << r.out;
  const std::string readme = test::ReadText(std::string(BRDFKIT_SOURCE_DIR) + "/README.md");
  const std::size_t begin = readme.find("| model | parameters");
  ASSERT_NE(begin, std::string::npos) << "README.md has no model table";
  const std::size_t end = readme.find("\n\n", begin);
  ASSERT_NE(end, std::string::npos);
  EXPECT_EQ(readme.substr(begin, end + 1 - begin), r.out)
      << "regenerate the README's table with: build/brdfkit models --markdown";
}

}  // namespace
}  // namespace brdfkit
