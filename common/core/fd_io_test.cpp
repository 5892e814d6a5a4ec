#include "common/core/fd_io.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <string>

namespace d3d {
namespace {

TEST(FdIo, WholeWritesAndReadsAtOffsetsAndWhatAShortOneSays) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  const int fd = fileno(f);
  const std::string a(100000, 'a'), b = "tail";
  EXPECT_EQ(PwriteFull(fd, a.data(), a.size(), 0), a.size());
  EXPECT_EQ(PwriteFull(fd, b.data(), b.size(), 200000),
            b.size());  // past the end: a hole before it
  std::string back(a.size(), '\0');
  EXPECT_EQ(PreadFull(fd, back.data(), back.size(), 0), back.size());
  EXPECT_EQ(back, a);
  std::string hole(8, 'x');
  EXPECT_EQ(PreadFull(fd, hole.data(), hole.size(), 150000), hole.size());
  EXPECT_EQ(hole, std::string(8, '\0'));
  // Reading across the end: the bytes there, then errno 0 (the file ended, not an error).
  std::string end(10, '\0');
  errno = EIO;
  EXPECT_EQ(PreadFull(fd, end.data(), end.size(), 200000), b.size());
  EXPECT_EQ(errno, 0);
  EXPECT_EQ(end.substr(0, b.size()), b);
  std::fclose(f);
  // A failed call: nothing done, errno from the system call.
  EXPECT_EQ(PreadFull(-1, end.data(), end.size(), 0), 0u);
  EXPECT_EQ(errno, EBADF);
  EXPECT_EQ(PwriteFull(-1, b.data(), b.size(), 0), 0u);
  EXPECT_EQ(errno, EBADF);
}

}  // namespace
}  // namespace d3d
