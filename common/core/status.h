// Status values for I/O and protocol (mcap style: a code and a message), and the set-up checks
// that throw on contract violations (COLMAP's THROW_CHECK style).
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>

namespace d3d {

enum class StatusCode {
  kOk = 0,
  kInvalidArgument,  // the caller passed something that cannot be used
  kNotFound,         // file, device or key missing
  kIoError,          // the OS refused a read or write
  kParseError,       // malformed content (wrong magic, bad header, truncated)
  kUnsupported,      // valid but not handled (e.g. a newer format version)
  kCorrupt,          // content fails an integrity check
  kUnavailable,      // a device or peer is not there (no camera, no probe)
  kInternal,
};

const char* StatusCodeName(StatusCode code);

// Result of an operation that can fail for expected reasons. Cheap to copy when ok.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}
  static Status Ok() { return {}; }

  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }
  // "PARSE_ERROR: ply header: no 'end_header'" or "OK".
  std::string ToString() const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

inline Status InvalidArgument(std::string m) {
  return {StatusCode::kInvalidArgument, std::move(m)};
}
inline Status NotFound(std::string m) { return {StatusCode::kNotFound, std::move(m)}; }
inline Status IoError(std::string m) { return {StatusCode::kIoError, std::move(m)}; }
inline Status ParseError(std::string m) { return {StatusCode::kParseError, std::move(m)}; }
inline Status Unsupported(std::string m) { return {StatusCode::kUnsupported, std::move(m)}; }
inline Status Corrupt(std::string m) { return {StatusCode::kCorrupt, std::move(m)}; }
inline Status Unavailable(std::string m) { return {StatusCode::kUnavailable, std::move(m)}; }

namespace internal {
[[noreturn]] void ThrowCheckFailure(const char* file, int line, const char* expr,
                                    const std::string& msg);
}  // namespace internal

}  // namespace d3d

// Contract checks at set-up time: throw std::invalid_argument naming file, line and expression.
// D3D_CHECK(x > 0);  D3D_CHECK_MSG(x > 0, "width must be positive, got " << x);
#define D3D_CHECK(expr)                                                             \
  do {                                                                              \
    if (!(expr)) ::d3d::internal::ThrowCheckFailure(__FILE__, __LINE__, #expr, ""); \
  } while (0)
#define D3D_CHECK_MSG(expr, stream)                                                       \
  do {                                                                                    \
    if (!(expr)) {                                                                        \
      std::ostringstream d3d_check_os_;                                                   \
      d3d_check_os_ << stream;                                                            \
      ::d3d::internal::ThrowCheckFailure(__FILE__, __LINE__, #expr, d3d_check_os_.str()); \
    }                                                                                     \
  } while (0)
// Propagate a non-ok Status from a function that returns Status.
#define D3D_RETURN_IF_ERROR(expr)              \
  do {                                         \
    ::d3d::Status d3d_status_ = (expr);        \
    if (!d3d_status_.ok()) return d3d_status_; \
  } while (0)
