#include "common/core/status.h"

namespace d3d {

const char* StatusCodeName(StatusCode code) {
  switch (code) {
    case StatusCode::kOk:
      return "OK";
    case StatusCode::kInvalidArgument:
      return "INVALID_ARGUMENT";
    case StatusCode::kNotFound:
      return "NOT_FOUND";
    case StatusCode::kIoError:
      return "IO_ERROR";
    case StatusCode::kParseError:
      return "PARSE_ERROR";
    case StatusCode::kUnsupported:
      return "UNSUPPORTED";
    case StatusCode::kCorrupt:
      return "CORRUPT";
    case StatusCode::kUnavailable:
      return "UNAVAILABLE";
    case StatusCode::kInternal:
      return "INTERNAL";
  }
  return "UNKNOWN";
}

std::string Status::ToString() const {
  if (ok()) return "OK";
  return std::string(StatusCodeName(code_)) + ": " + message_;
}

namespace internal {
void ThrowCheckFailure(const char* file, int line, const char* expr, const std::string& msg) {
  std::ostringstream os;
  os << "check failed: " << expr;
  if (!msg.empty()) os << " (" << msg << ")";
  os << " at " << file << ":" << line;
  throw std::invalid_argument(os.str());
}
}  // namespace internal

}  // namespace d3d
