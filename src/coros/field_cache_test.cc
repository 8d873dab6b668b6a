// The field cache as the agents of one host use it: a field stored by one is read by the others
// and gives the same path lengths as one computed anew; agent processes asking for the same
// field at once compute it once; another map's file, or one cut short, is never read.
#include "icars/coros/field_cache.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <vector>

#include "icars/coros/messages.h"
#include "icars/sim/house.h"
#include "test_directory.h"

namespace icars::coros {
namespace {

const std::string kMap = std::string(ICARS_HOUSES_DIR) + "/paper_house.xml";

class FieldCacheTest : public ::testing::Test {
 protected:
  sim::House house_ = sim::load_house(kMap);
  sim::OccupancyGrid grid_{house_, 0.25};
  sim::Point goal_ = *house_.locate("bedroom_window");
  planet_test::TestDirectory dir_{"coros_field_cache"};
};

TEST_F(FieldCacheTest, AFieldStoredByOneAgentIsReadByTheOthers) {
  const FieldCache first(dir_ / "fields", grid_);  // the directory is made
  const auto computed = first.field(goal_);
  EXPECT_EQ(first.computed(), 1u);
  EXPECT_TRUE(std::filesystem::exists(first.file_of(goal_)));

  const FieldCache second(dir_ / "fields", grid_);
  const auto read = second.field(goal_);
  EXPECT_EQ(second.computed(), 0u);
  EXPECT_EQ(read->distances(), computed->distances());
  const sim::DistanceField fresh(grid_, goal_);
  for (const char* from : {"entrance", "kitchen_corner", "sofa_side", "desk"}) {
    const auto p = *house_.locate(from);
    ASSERT_TRUE(fresh.length_from(p)) << from;
    EXPECT_EQ(read->length_from(p), fresh.length_from(p)) << from;
  }
}

TEST_F(FieldCacheTest, AgentProcessesAskingAtOnceComputeTheFieldOnce) {
  const sim::DistanceField reference(grid_, goal_);
  constexpr int kAgents = 4;
  std::vector<pid_t> children;
  for (int i = 0; i < kAgents; ++i) {
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      // 0: read it, 1: computed it, 2: a wrong field.
      const FieldCache cache(dir_ / "fields", grid_);
      const auto f = cache.field(goal_);
      ::_exit(f->distances() != reference.distances() ? 2 : static_cast<int>(cache.computed()));
    }
    children.push_back(pid);
  }
  int computed = 0;
  for (const pid_t pid : children) {
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    ASSERT_TRUE(WIFEXITED(status));
    ASSERT_NE(WEXITSTATUS(status), 2) << "an agent got a field unlike the one computed here";
    computed += WEXITSTATUS(status);
  }
  EXPECT_EQ(computed, 1);
}

TEST_F(FieldCacheTest, AnotherMapsOrABrokenFileIsComputedAgain) {
  // A wider robot's grid is another map for the cache: its own file.
  const sim::OccupancyGrid wide(house_, 0.3);
  const FieldCache narrow_cache(dir_.path(), grid_);
  const FieldCache wide_cache(dir_.path(), wide);
  EXPECT_NE(narrow_cache.file_of(goal_), wide_cache.file_of(goal_));
  narrow_cache.field(goal_);
  wide_cache.field(goal_);
  EXPECT_EQ(wide_cache.computed(), 1u);

  // Cut short: computed again and the file replaced whole.
  const auto file = narrow_cache.file_of(goal_);
  const auto size = std::filesystem::file_size(file);
  std::filesystem::resize_file(file, size / 2);
  const FieldCache again(dir_.path(), grid_);
  const auto f = again.field(goal_);
  EXPECT_EQ(again.computed(), 1u);
  EXPECT_EQ(f->distances(), sim::DistanceField(grid_, goal_).distances());
  EXPECT_EQ(std::filesystem::file_size(file), size);
}

TEST_F(FieldCacheTest, ADirectoryThatCannotBeMadeIsAConfigurationError) {
  const auto file = dir_ / "a_file";
  { std::ofstream(file) << "x"; }
  try {
    FieldCache cache(file / "fields", grid_);
    FAIL() << "no error";
  } catch (const CorosError& e) {
    EXPECT_NE(std::string(e.what()).find("a_file/fields"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace icars::coros
