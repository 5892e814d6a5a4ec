#include "common/core/npy_io.h"

#include <cstring>
#include <fstream>
#include <sstream>

namespace d3d {
namespace {

const char* Descr(NpyType t) {
  switch (t) {
    case NpyType::kFloat32:
      return "<f4";
    case NpyType::kFloat64:
      return "<f8";
    case NpyType::kUint8:
      return "|u1";
    case NpyType::kUint16:
      return "<u2";
    case NpyType::kInt32:
      return "<i4";
  }
  return "";
}

bool TypeFromDescr(const std::string& d, NpyType* t) {
  if (d == "<f4")
    *t = NpyType::kFloat32;
  else if (d == "<f8")
    *t = NpyType::kFloat64;
  else if (d == "|u1" || d == "<u1")
    *t = NpyType::kUint8;
  else if (d == "<u2")
    *t = NpyType::kUint16;
  else if (d == "<i4")
    *t = NpyType::kInt32;
  else
    return false;
  return true;
}

// Value of 'key': in the header dict, as raw text up to the next top-level ',' or '}'.
bool DictValue(const std::string& header, const std::string& key, std::string* value) {
  const std::string k = "'" + key + "'";
  size_t p = header.find(k);
  if (p == std::string::npos) return false;
  p = header.find(':', p + k.size());
  if (p == std::string::npos) return false;
  ++p;
  while (p < header.size() && header[p] == ' ') ++p;
  int depth = 0;
  size_t e = p;
  for (; e < header.size(); ++e) {
    const char c = header[e];
    if (c == '(') ++depth;
    if (c == ')') --depth;
    if (depth == 0 && (c == ',' || c == '}')) break;
  }
  *value = header.substr(p, e - p);
  return true;
}

}  // namespace

int NpyArray::ElementSize(NpyType type) {
  switch (type) {
    case NpyType::kFloat32:
      return 4;
    case NpyType::kFloat64:
      return 8;
    case NpyType::kUint8:
      return 1;
    case NpyType::kUint16:
      return 2;
    case NpyType::kInt32:
      return 4;
  }
  return 0;
}

int64_t NpyArray::NumElements() const {
  int64_t n = 1;
  for (int64_t s : shape) n *= s;
  return n;
}

Status WriteNpy(const std::string& path, NpyType type, const std::vector<int64_t>& shape,
                const void* data) {
  std::ostringstream dict;
  dict << "{'descr': '" << Descr(type) << "', 'fortran_order': False, 'shape': (";
  int64_t n = 1;
  for (size_t i = 0; i < shape.size(); ++i) {
    if (shape[i] < 0) return InvalidArgument("npy: negative dimension");
    dict << shape[i] << (shape.size() == 1 || i + 1 < shape.size() ? "," : "");
    if (i + 1 < shape.size()) dict << " ";
    n *= shape[i];
  }
  dict << "), }";
  std::string header = dict.str();
  // Pad so that magic(6) + version(2) + len(2) + header + '\n' is a multiple of 64.
  const size_t unpadded = 10 + header.size() + 1;
  header.append((64 - unpadded % 64) % 64, ' ');
  header.push_back('\n');
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) return IoError("npy: cannot open '" + path + "' for writing");
  const char magic[8] = {'\x93', 'N', 'U', 'M', 'P', 'Y', 1, 0};
  f.write(magic, 8);
  const uint16_t len = static_cast<uint16_t>(header.size());
  const char len_le[2] = {static_cast<char>(len & 0xff), static_cast<char>(len >> 8)};
  f.write(len_le, 2);
  f.write(header.data(), static_cast<std::streamsize>(header.size()));
  f.write(static_cast<const char*>(data),
          static_cast<std::streamsize>(n * NpyArray::ElementSize(type)));
  if (!f) return IoError("npy: write failed for '" + path + "'");
  return Status::Ok();
}

Status ReadNpy(const std::string& path, NpyArray* out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return NotFound("npy: cannot open '" + path + "'");
  const std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const Status s = ParseNpy(bytes, out);
  return s.ok() ? s : Status(s.code(), s.message() + " ('" + path + "')");
}

Status ParseNpy(std::string_view bytes, NpyArray* out) {
  if (bytes.size() < 10) return ParseError("npy: too short for a header");
  const auto* pre = reinterpret_cast<const unsigned char*>(bytes.data());
  if (std::memcmp(pre, "\x93NUMPY", 6) != 0) return ParseError("npy: no NUMPY magic");
  size_t header_len = 0, offset = 10;
  if (pre[6] == 1) {
    header_len = pre[8] | (pre[9] << 8);
  } else if (pre[6] == 2 || pre[6] == 3) {
    if (bytes.size() < 12) return ParseError("npy: truncated header length");
    header_len = pre[8] | (pre[9] << 8) | (pre[10] << 16) | (static_cast<size_t>(pre[11]) << 24);
    offset = 12;
  } else {
    return Unsupported("npy: format version " + std::to_string(pre[6]));
  }
  if (header_len > (1u << 20))
    return ParseError("npy: header length " + std::to_string(header_len) + " is implausible");
  if (bytes.size() < offset + header_len) return ParseError("npy: truncated header");
  const std::string header(bytes.substr(offset, header_len));
  std::string descr, fortran, shape;
  if (!DictValue(header, "descr", &descr) || !DictValue(header, "fortran_order", &fortran) ||
      !DictValue(header, "shape", &shape)) {
    return ParseError("npy: header lacks descr/fortran_order/shape");
  }
  if (descr.size() < 2) return ParseError("npy: bad descr");
  descr = descr.substr(1, descr.size() - 2);
  NpyArray a;
  if (!TypeFromDescr(descr, &a.type)) return Unsupported("npy: dtype '" + descr + "'");
  if (fortran.rfind("False", 0) != 0) return Unsupported("npy: Fortran order");
  if (shape.empty() || shape.front() != '(') return ParseError("npy: bad shape '" + shape + "'");
  std::istringstream ds(shape.substr(1));
  std::string tok;
  const size_t payload = bytes.size() - offset - header_len;
  uint64_t n = 1;
  while (std::getline(ds, tok, ',')) {
    const size_t b = tok.find_first_not_of(" )");
    if (b == std::string::npos) continue;
    try {
      const long long v = std::stoll(tok.substr(b));
      if (v < 0) return ParseError("npy: negative dimension");
      a.shape.push_back(v);
      n *= static_cast<uint64_t>(v);
      if (v > 0 && n > payload)
        return Corrupt("npy: data is shorter than its header says");  // before any allocation
    } catch (const std::exception&) {
      return ParseError("npy: bad shape '" + shape + "'");
    }
    if (a.shape.size() > 16) return ParseError("npy: too many dimensions");
  }
  const uint64_t size = n * static_cast<uint64_t>(NpyArray::ElementSize(a.type));
  if (size > payload) return Corrupt("npy: data is shorter than its header says");
  a.bytes.assign(bytes.begin() + static_cast<long>(offset + header_len),
                 bytes.begin() + static_cast<long>(offset + header_len + size));
  *out = std::move(a);
  return Status::Ok();
}

}  // namespace d3d
