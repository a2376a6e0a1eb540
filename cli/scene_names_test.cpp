// The scene schema's enumerations are the names the tool itself accepts
// and prints (`brdfkit run --names`, from the libraries' own lists): each
// list of the tool is an enumeration of the schema and each enumeration of
// the schema is a list of the tool.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <set>
#include <string>
#include <vector>

#include "tests/cli_util.h"

namespace brdfkit {
namespace {

using nlohmann::json;
using Names = std::set<std::string>;

void CollectEnums(const json& j, std::vector<Names>& out) {
  if (j.is_object()) {
    for (auto it = j.begin(); it != j.end(); ++it) {
      if (it.key() == "enum" && it.value().is_array()) out.push_back(it.value().get<Names>());
      else CollectEnums(it.value(), out);
    }
  } else if (j.is_array()) {
    for (const json& e : j) CollectEnums(e, out);
  }
}

TEST(SceneNames, SchemaListsTheToolsNames) {
  const test::CliRun r = test::Brdfkit("run --names");
  ASSERT_EQ(r.code, 0) << r.out;
  const json names = json::parse(r.out);
  const json schema =
      json::parse(test::ReadText(std::string(BRDFKIT_SOURCE_DIR) + "/examples/scene.schema.json"));
  std::vector<Names> enums;
  CollectEnums(schema, enums);
  ASSERT_FALSE(enums.empty());
  std::vector<Names> lists;
  for (auto it = names.begin(); it != names.end(); ++it) {
    lists.push_back(it.value().get<Names>());
    EXPECT_NE(std::find(enums.begin(), enums.end(), lists.back()), enums.end())
        << "the schema has no enumeration of the tool's " << it.key() << ": " << it.value().dump();
  }
  for (const Names& e : enums)
    EXPECT_NE(std::find(lists.begin(), lists.end(), e), lists.end())
        << "the schema enumerates " << json(e).dump() << ", which the tool does not print";
}

}  // namespace
}  // namespace brdfkit
