#include "common/core/status.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

Status FailsWith(StatusCode code) { return {code, "why"}; }
Status Propagates() {
  D3D_RETURN_IF_ERROR(FailsWith(StatusCode::kCorrupt));
  return Status::Ok();
}

TEST(Status, OkAndErrorStrings) {
  EXPECT_TRUE(Status::Ok().ok());
  EXPECT_EQ(Status::Ok().ToString(), "OK");
  const Status s = ParseError("ply header: no end_header");
  EXPECT_FALSE(s.ok());
  EXPECT_EQ(s.ToString(), "PARSE_ERROR: ply header: no end_header");
}

TEST(Status, ReturnIfErrorPropagates) {
  const Status s = Propagates();
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
}

TEST(Check, ThrowsWithExpressionAndMessage) {
  const int width = -3;
  try {
    D3D_CHECK_MSG(width > 0, "width must be positive, got " << width);
    FAIL() << "no throw";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("width > 0"), std::string::npos) << what;
    EXPECT_NE(what.find("got -3"), std::string::npos) << what;
  }
  EXPECT_NO_THROW(D3D_CHECK(width < 0));
}

}  // namespace
}  // namespace d3d
