#include "core/params.h"

#include "test_util.h"

namespace compose {
namespace {

TEST(ParamSet, ParsesAndReadsTypedValues) {
  ParamSet p = ParamSet::parse("order=3,scale=0.25,window=hanning", "test");
  EXPECT_EQ(p.getInt("order", 0, "test"), 3);
  EXPECT_DOUBLE_EQ(p.getDouble("scale", 1.0, "test"), 0.25);
  EXPECT_EQ(p.getString("window", "none"), "hanning");
  EXPECT_EQ(p.getInt("missing", 7, "test"), 7);
  EXPECT_TRUE(p.unusedNames().empty());
}

TEST(ParamSet, ReportsUnusedParameters) {
  ParamSet p = ParamSet::parse("order=3,ordr=4", "lighting");
  p.getInt("order", 0, "lighting");
  ASSERT_EQ(p.unusedNames(), std::vector<std::string>{"ordr"});
  COMPOSE_EXPECT_ERROR(p.requireAllUsed("lighting", "basis 'sh'"),
                       "basis 'sh' does not take parameter(s): ordr");
}

TEST(ParamSet, RejectsMalformedText) {
  COMPOSE_EXPECT_ERROR(ParamSet::parse("order", "lighting"), "malformed parameter 'order'");
  // An empty piece is a slip (a value lost, or a comma too many), not nothing.
  COMPOSE_EXPECT_ERROR(ParamSet::parse("order=2,", "lighting"),
                       "malformed parameters 'order=2,': an empty one after the last comma");
  COMPOSE_EXPECT_ERROR(ParamSet::parse("order=2,,rows=3", "lighting"),
                       "an empty one between commas");
  COMPOSE_EXPECT_ERROR(ParamSet::parse(",order=2", "lighting"),
                       "an empty one before the first comma");
  EXPECT_TRUE(ParamSet::parse("", "lighting").unusedNames().empty());
  ParamSet p = ParamSet::parse("order=two,x=1.5e", "lighting");
  COMPOSE_EXPECT_ERROR(p.getInt("order", 0, "lighting"), "order='two' is not an integer");
  COMPOSE_EXPECT_ERROR(p.getDouble("x", 0, "lighting"), "x='1.5e' is not a number");
}

TEST(Error, DescribesStageWhatAndFile) {
  const Error e("ingest", "file not found", "/tmp/plate.jpg");
  EXPECT_EQ(e.describe(), "ingest: file not found (/tmp/plate.jpg)");
  EXPECT_EQ(Error("cli", "bad").describe(), "cli: bad");
}

}  // namespace
}  // namespace compose
