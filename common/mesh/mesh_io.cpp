#include "common/mesh/mesh_io.h"

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <limits>
#include <new>
#include <sstream>
#include <unordered_map>
#include <vector>

namespace d3d {
namespace {

// ------------------------------------------------------------------------------------------------
// Text and byte helpers

template <typename... Args>
std::string Cat(const Args&... args) {
  std::ostringstream os;
  os << std::setprecision(10);
  (os << ... << args);
  return os.str();
}

bool IsSpace(char c) {
  return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f';
}

char ToLower(char c) { return (c >= 'A' && c <= 'Z') ? static_cast<char>(c - 'A' + 'a') : c; }

std::string_view Trim(std::string_view s) {
  while (!s.empty() && IsSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && IsSpace(s.back())) s.remove_suffix(1);
  return s;
}

bool EqualsIgnoreCase(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if (ToLower(a[i]) != ToLower(b[i])) return false;
  }
  return true;
}

bool StartsWithIgnoreCase(std::string_view s, std::string_view prefix) {
  return s.size() >= prefix.size() && EqualsIgnoreCase(s.substr(0, prefix.size()), prefix);
}

void SplitWhitespace(std::string_view line, std::vector<std::string_view>* tokens) {
  tokens->clear();
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && IsSpace(line[i])) ++i;
    const size_t start = i;
    while (i < line.size() && !IsSpace(line[i])) ++i;
    if (i > start) tokens->push_back(line.substr(start, i - start));
  }
}

// A token for an error message: quoted, at most 24 characters, non-printables as \xNN.
std::string Quote(std::string_view token) {
  constexpr size_t kMax = 24;
  std::string out = "'";
  for (size_t i = 0; i < token.size() && i < kMax; ++i) {
    const auto c = static_cast<unsigned char>(token[i]);
    if (c >= 0x20 && c < 0x7f) {
      out += static_cast<char>(c);
    } else {
      static constexpr char kHex[] = "0123456789abcdef";
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    }
  }
  if (token.size() > kMax) out += "...";
  return out + "'";
}

// A value read as double, printed as an integer when it is one (indices, counts).
std::string FormatValue(double v) {
  if (std::isfinite(v) && v == std::floor(v) && std::fabs(v) < 1e18) {
    return std::to_string(static_cast<int64_t>(v));
  }
  return Cat(v);
}

// The whole token as a number (a leading '+' allowed; "nan" and "inf" parse as such for doubles).
template <typename T>
bool ParseNumber(std::string_view token, T* value) {
  if (token.size() > 1 && token[0] == '+' && token[1] != '-') token.remove_prefix(1);
  const char* end = token.data() + token.size();
  const auto [ptr, ec] = std::from_chars(token.data(), end, *value);
  return ec == std::errc() && ptr == end;
}
bool ParseDouble(std::string_view token, double* value) { return ParseNumber(token, value); }
bool ParseInt64(std::string_view token, int64_t* value) { return ParseNumber(token, value); }

bool IsFinite(const Eigen::Vector3d& v) { return v.allFinite(); }

constexpr double kFloatMax = std::numeric_limits<float>::max();

// `v` rounded to float; ±inf beyond float's range (where a plain cast is undefined).
double ToFloatPrecision(double v) {
  if (std::fabs(v) > kFloatMax) return std::copysign(std::numeric_limits<double>::infinity(), v);
  return static_cast<float>(v);
}

bool FitsFloat(const Eigen::Vector3d& v) {
  return v.allFinite() && v.cwiseAbs().maxCoeff() <= kFloatMax;
}

// Reads a T stored at `p` with the given byte order.
template <typename T>
T LoadScalar(const char* p, bool big_endian) {
  std::array<char, sizeof(T)> b;
  std::memcpy(b.data(), p, sizeof(T));
  if (big_endian != (std::endian::native == std::endian::big)) std::reverse(b.begin(), b.end());
  T v;
  std::memcpy(&v, b.data(), sizeof(T));
  return v;
}

// Appends a T in little-endian byte order.
template <typename T>
void AppendLittleEndian(std::string* out, T v) {
  std::array<char, sizeof(T)> b;
  std::memcpy(b.data(), &v, sizeof(T));
  if constexpr (std::endian::native == std::endian::big) std::reverse(b.begin(), b.end());
  out->append(b.data(), b.size());
}

// A Status with the same code and `prefix` put before the message.
Status Prefixed(const std::string& prefix, const Status& status) {
  if (status.ok()) return status;
  return {status.code(), prefix + status.message()};
}

// Whitespace-separated tokens of a text, with the line number of the last token returned.
class TextTokenizer {
 public:
  explicit TextTokenizer(std::string_view text) : text_(text) {}

  // The next token, empty at the end of the text.
  std::string_view Next() {
    SkipSpace();
    const size_t start = pos_;
    while (pos_ < text_.size() && !IsSpace(text_[pos_])) ++pos_;
    return text_.substr(start, pos_ - start);
  }
  // Skips to the start of the next line.
  void SkipLine() {
    while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
  }
  int line() const { return line_; }
  size_t remaining() const { return text_.size() - pos_; }

 private:
  void SkipSpace() {
    while (pos_ < text_.size() && IsSpace(text_[pos_])) {
      if (text_[pos_] == '\n') ++line_;
      ++pos_;
    }
  }

  std::string_view text_;
  size_t pos_ = 0;
  int line_ = 1;
};

// Merges corners with bit-identical positions into one vertex (STL stores triangle soups).
class VertexWelder {
 public:
  explicit VertexWelder(TriangleMesh* mesh) : mesh_(mesh) {}

  int Add(const Eigen::Vector3d& p_in) {
    const Eigen::Vector3d p = p_in + Eigen::Vector3d::Zero();  // -0.0 → +0.0
    Key key;
    for (int k = 0; k < 3; ++k) key.bits[static_cast<size_t>(k)] = std::bit_cast<uint64_t>(p[k]);
    const auto [it, inserted] = index_.try_emplace(key, static_cast<int>(mesh_->vertices.size()));
    if (inserted) mesh_->vertices.push_back(p);
    return it->second;
  }

 private:
  struct Key {
    std::array<uint64_t, 3> bits{};
    bool operator==(const Key&) const = default;
  };
  struct KeyHash {
    size_t operator()(const Key& k) const {
      uint64_t h = 1469598103934665603ull;
      for (uint64_t b : k.bits) h = (h ^ b) * 1099511628211ull + (h >> 29);
      return static_cast<size_t>(h);
    }
  };

  TriangleMesh* mesh_;
  std::unordered_map<Key, int, KeyHash> index_;
};

// Appends the fan triangulation (c0, ci, ci+1) of a polygon.
void AppendFan(const std::vector<int>& corners, TriangleMesh* mesh) {
  for (size_t i = 1; i + 1 < corners.size(); ++i)
    mesh->faces.emplace_back(corners[0], corners[i], corners[i + 1]);
}

// ------------------------------------------------------------------------------------------------
// PLY

enum class PlyType : uint8_t {
  kInt8,
  kUint8,
  kInt16,
  kUint16,
  kInt32,
  kUint32,
  kFloat32,
  kFloat64
};
enum class PlyEncoding { kAscii, kBinaryLittleEndian, kBinaryBigEndian };

struct PlyTypeInfo {
  std::string_view name;
  std::string_view alias;
  size_t size;
  double min;
  double max;
};

constexpr double kUnbounded = std::numeric_limits<double>::infinity();
constexpr std::array<PlyTypeInfo, 8> kPlyTypes = {{
    {"char", "int8", 1, -128.0, 127.0},
    {"uchar", "uint8", 1, 0.0, 255.0},
    {"short", "int16", 2, -32768.0, 32767.0},
    {"ushort", "uint16", 2, 0.0, 65535.0},
    {"int", "int32", 4, -2147483648.0, 2147483647.0},
    {"uint", "uint32", 4, 0.0, 4294967295.0},
    {"float", "float32", 4, -kUnbounded, kUnbounded},
    {"double", "float64", 8, -kUnbounded, kUnbounded},
}};

const PlyTypeInfo& Info(PlyType t) { return kPlyTypes[static_cast<size_t>(t)]; }
bool IsFloat(PlyType t) { return t == PlyType::kFloat32 || t == PlyType::kFloat64; }

bool ParsePlyType(std::string_view name, PlyType* type) {
  for (size_t i = 0; i < kPlyTypes.size(); ++i) {
    if (name == kPlyTypes[i].name || name == kPlyTypes[i].alias) {
      *type = static_cast<PlyType>(i);
      return true;
    }
  }
  return false;
}

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat32;  // of the value, or of the list items
  bool is_list = false;
  PlyType count_type = PlyType::kUint8;
};

struct PlyElement {
  std::string name;
  uint64_t count = 0;
  std::vector<PlyProperty> properties;

  // Index of the first property called one of `names`, or -1.
  int Find(std::initializer_list<std::string_view> names, bool list) const {
    for (size_t i = 0; i < properties.size(); ++i) {
      if (properties[i].is_list != list) continue;
      for (std::string_view n : names) {
        if (properties[i].name == n) return static_cast<int>(i);
      }
    }
    return -1;
  }
};

struct PlyHeader {
  PlyEncoding encoding = PlyEncoding::kAscii;
  std::vector<PlyElement> elements;
  size_t body_offset = 0;  // first byte after "end_header\n"
};

bool IsPlyMagic(std::string_view bytes) {
  return bytes.size() >= 4 && bytes.substr(0, 3) == "ply" && IsSpace(bytes[3]);
}

Status HeaderError(int line, const std::string& what) {
  return ParseError(Cat("ply header line ", line, ": ", what));
}

Status ParsePlyFormat(const std::vector<std::string_view>& t, int line, PlyHeader* header) {
  if (t.size() < 2) return HeaderError(line, "malformed 'format' line");
  if (t[1] == "ascii") {
    header->encoding = PlyEncoding::kAscii;
  } else if (t[1] == "binary_little_endian") {
    header->encoding = PlyEncoding::kBinaryLittleEndian;
  } else if (t[1] == "binary_big_endian") {
    header->encoding = PlyEncoding::kBinaryBigEndian;
  } else {
    return Unsupported(Cat("ply header line ", line, ": unknown format ", Quote(t[1])));
  }
  return Status::Ok();
}

Status ParsePlyElement(const std::vector<std::string_view>& t, int line, PlyHeader* header) {
  PlyElement element;
  if (t.size() != 3)
    return HeaderError(line, "malformed 'element' line (want: element NAME COUNT)");
  element.name = std::string(t[1]);
  int64_t count = 0;
  if (!ParseInt64(t[2], &count) || count < 0) {
    return HeaderError(line, Cat("element '", element.name, "' has invalid count ", Quote(t[2])));
  }
  element.count = static_cast<uint64_t>(count);
  for (const PlyElement& e : header->elements) {
    if (e.name == element.name && (e.name == "vertex" || e.name == "face")) {
      return HeaderError(line, Cat("element '", element.name, "' declared twice"));
    }
  }
  header->elements.push_back(std::move(element));
  return Status::Ok();
}

Status ParsePlyProperty(const std::vector<std::string_view>& t, int line, PlyHeader* header) {
  if (header->elements.empty()) return HeaderError(line, "'property' before any 'element'");
  PlyProperty prop;
  if (t.size() >= 2 && t[1] == "list") {
    if (t.size() != 5)
      return HeaderError(line,
                         "malformed list property (want: property list COUNT_TYPE TYPE NAME)");
    prop.is_list = true;
    if (!ParsePlyType(t[2], &prop.count_type))
      return HeaderError(line, Cat("unknown list count type ", Quote(t[2])));
    if (!ParsePlyType(t[3], &prop.type))
      return HeaderError(line, Cat("unknown list item type ", Quote(t[3])));
    prop.name = std::string(t[4]);
  } else {
    if (t.size() != 3) return HeaderError(line, "malformed property (want: property TYPE NAME)");
    if (!ParsePlyType(t[1], &prop.type))
      return HeaderError(line, Cat("unknown property type ", Quote(t[1])));
    prop.name = std::string(t[2]);
  }
  header->elements.back().properties.push_back(std::move(prop));
  return Status::Ok();
}

// Parses the header up to and including "end_header"; the body starts at header->body_offset.
Status ParsePlyHeader(std::string_view bytes, PlyHeader* header) {
  if (!IsPlyMagic(bytes)) return ParseError("ply header: missing 'ply' magic on the first line");
  bool have_format = false;
  std::vector<std::string_view> tokens;
  size_t pos = 0;
  for (int line = 1;; ++line) {
    const size_t nl = bytes.find('\n', pos);
    if (nl == std::string_view::npos) return ParseError("ply header: no 'end_header'");
    SplitWhitespace(bytes.substr(pos, nl - pos), &tokens);
    pos = nl + 1;
    if (line == 1 || tokens.empty()) continue;  // "ply" magic, blank lines
    const std::string_view keyword = tokens[0];
    if (keyword == "end_header") {
      if (!have_format) return HeaderError(line, "'end_header' before any 'format' line");
      header->body_offset = pos;
      return Status::Ok();
    }
    if (keyword == "format") {
      D3D_RETURN_IF_ERROR(ParsePlyFormat(tokens, line, header));
      have_format = true;
    } else if (keyword == "element") {
      D3D_RETURN_IF_ERROR(ParsePlyElement(tokens, line, header));
    } else if (keyword == "property") {
      D3D_RETURN_IF_ERROR(ParsePlyProperty(tokens, line, header));
    } else if (keyword != "comment" && keyword != "obj_info") {
      return HeaderError(line, Cat("unknown keyword ", Quote(keyword)));
    }
  }
}

// Values of the PLY body, ascii tokens or binary scalars, read one at a time with bounds checks.
class PlyBodyReader {
 public:
  PlyBodyReader(std::string_view body, PlyEncoding encoding)
      : body_(body), encoding_(encoding), tokens_(body) {}

  // Reads one value of `type` (as double: exact for every PLY integer type). False with error()
  // set when the data ends or the ascii token is not a valid `type`.
  bool Read(PlyType type, double* value) {
    return encoding_ == PlyEncoding::kAscii ? ReadAscii(type, value) : ReadBinary(type, value);
  }

  // Whether `count` values of `type` can still fit in the data (a cheap upper bound for ascii).
  bool CanHold(PlyType type, uint64_t count) const {
    if (encoding_ == PlyEncoding::kAscii) return count <= (tokens_.remaining() + 1) / 2;
    return count <= (body_.size() - pos_) / Info(type).size;
  }

  // Skips `count` values of `type` (the items of a list nobody wants).
  bool Skip(PlyType type, uint64_t count) {
    if (!CanHold(type, count)) return Fail("unexpected end of data");
    if (encoding_ != PlyEncoding::kAscii) {
      pos_ += static_cast<size_t>(count) * Info(type).size;
      return true;
    }
    for (uint64_t i = 0; i < count; ++i) {
      if (tokens_.Next().empty()) return Fail("unexpected end of data");
    }
    return true;
  }

  // Bytes left after the current position.
  size_t remaining() const {
    return encoding_ == PlyEncoding::kAscii ? tokens_.remaining() : body_.size() - pos_;
  }
  const std::string& error() const { return error_; }

 private:
  bool Fail(std::string message) {
    error_ = std::move(message);
    return false;
  }

  bool ReadAscii(PlyType type, double* value) {
    const std::string_view token = tokens_.Next();
    if (token.empty()) return Fail("unexpected end of data");
    const PlyTypeInfo& info = Info(type);
    if (IsFloat(type)) {
      if (!ParseDouble(token, value)) return Fail(Cat(Quote(token), " is not a ", info.name));
      // Rounded as the binary encoding would be, so ascii and binary files load alike.
      if (type == PlyType::kFloat32) *value = ToFloatPrecision(*value);
      return true;
    }
    int64_t v = 0;
    if (!ParseInt64(token, &v)) return Fail(Cat(Quote(token), " is not a ", info.name));
    *value = static_cast<double>(v);
    if (*value < info.min || *value > info.max)
      return Fail(Cat(v, " is out of range for ", info.name));
    return true;
  }

  bool ReadBinary(PlyType type, double* value) {
    const size_t size = Info(type).size;
    if (body_.size() - pos_ < size) return Fail("unexpected end of data");
    const char* p = body_.data() + pos_;
    const bool big = encoding_ == PlyEncoding::kBinaryBigEndian;
    pos_ += size;
    switch (type) {
      case PlyType::kInt8:
        *value = LoadScalar<int8_t>(p, big);
        break;
      case PlyType::kUint8:
        *value = LoadScalar<uint8_t>(p, big);
        break;
      case PlyType::kInt16:
        *value = LoadScalar<int16_t>(p, big);
        break;
      case PlyType::kUint16:
        *value = LoadScalar<uint16_t>(p, big);
        break;
      case PlyType::kInt32:
        *value = LoadScalar<int32_t>(p, big);
        break;
      case PlyType::kUint32:
        *value = LoadScalar<uint32_t>(p, big);
        break;
      case PlyType::kFloat32:
        *value = LoadScalar<float>(p, big);
        break;
      case PlyType::kFloat64:
        *value = LoadScalar<double>(p, big);
        break;
    }
    return true;
  }

  std::string_view body_;
  PlyEncoding encoding_;
  size_t pos_ = 0;        // binary
  TextTokenizer tokens_;  // ascii
  std::string error_;
};

// Refuses an element whose count the remaining data cannot hold, before anything is allocated:
// each item takes at least one byte per scalar/list count in binary, two (value + separator) in
// ascii.
Status CheckElementFits(const PlyElement& element, PlyEncoding encoding, size_t remaining) {
  uint64_t min_bytes = 0;
  for (const PlyProperty& p : element.properties) {
    if (encoding == PlyEncoding::kAscii) {
      min_bytes += 2;
    } else {
      min_bytes += Info(p.is_list ? p.count_type : p.type).size;
    }
  }
  if (min_bytes == 0 || element.count == 0) return Status::Ok();
  const uint64_t room = encoding == PlyEncoding::kAscii ? remaining + 1 : remaining;
  if (element.count > room / min_bytes) {
    return ParseError(Cat("ply: header claims ", element.count, " '", element.name,
                          "' items of at least ", min_bytes, " bytes each, but only ", remaining,
                          " bytes of data remain (truncated or corrupt count)"));
  }
  return Status::Ok();
}

Status ItemError(const PlyElement& element, uint64_t item, const PlyProperty& prop,
                 const std::string& what) {
  return ParseError(Cat("ply: ", element.name, " ", item, " property '", prop.name, "': ", what));
}

// Reads one item: scalar properties into (*scalars)[i], the items of list property `keep_list`
// into *list; other lists are skipped.
Status ReadPlyItem(const PlyElement& element, uint64_t item, int keep_list, PlyBodyReader* reader,
                   std::vector<double>* scalars, std::vector<double>* list) {
  list->clear();
  for (size_t p = 0; p < element.properties.size(); ++p) {
    const PlyProperty& prop = element.properties[p];
    if (!prop.is_list) {
      if (!reader->Read(prop.type, &(*scalars)[p]))
        return ItemError(element, item, prop, reader->error());
      continue;
    }
    double count_value = 0.0;
    if (!reader->Read(prop.count_type, &count_value))
      return ItemError(element, item, prop, reader->error());
    if (!(count_value >= 0.0) || count_value != std::floor(count_value)) {
      return ItemError(element, item, prop,
                       Cat("list count ", FormatValue(count_value), " is not a count"));
    }
    const auto count = static_cast<uint64_t>(std::min(count_value, 1e19));
    if (!reader->CanHold(prop.type, count)) {
      return ItemError(element, item, prop,
                       Cat("list of ", count, " items does not fit in the remaining ",
                           reader->remaining(), " bytes"));
    }
    if (static_cast<int>(p) != keep_list) {
      if (!reader->Skip(prop.type, count)) return ItemError(element, item, prop, reader->error());
      continue;
    }
    list->reserve(static_cast<size_t>(count));
    for (uint64_t i = 0; i < count; ++i) {
      double v = 0.0;
      if (!reader->Read(prop.type, &v)) return ItemError(element, item, prop, reader->error());
      list->push_back(v);
    }
  }
  return Status::Ok();
}

// Skips every item of an element we do not use (edge, material, ...).
Status SkipPlyElement(const PlyElement& element, PlyBodyReader* reader) {
  if (element.properties.empty()) return Status::Ok();
  std::vector<double> scalars(element.properties.size());
  std::vector<double> unused;
  for (uint64_t i = 0; i < element.count; ++i) {
    D3D_RETURN_IF_ERROR(ReadPlyItem(element, i, -1, reader, &scalars, &unused));
  }
  return Status::Ok();
}

Status ReadPlyVertices(const PlyElement& element, PlyBodyReader* reader, TriangleMesh* mesh) {
  const std::array<int, 3> xyz = {element.Find({"x"}, false), element.Find({"y"}, false),
                                  element.Find({"z"}, false)};
  const std::array<int, 3> nxyz = {element.Find({"nx"}, false), element.Find({"ny"}, false),
                                   element.Find({"nz"}, false)};
  if (*std::min_element(xyz.begin(), xyz.end()) < 0)
    return ParseError("ply: vertex element lacks x, y or z");
  if (element.count > static_cast<uint64_t>(std::numeric_limits<int>::max())) {
    return ParseError(Cat("ply: ", element.count, " vertices is more than a mesh can index"));
  }
  const bool has_normals = *std::min_element(nxyz.begin(), nxyz.end()) >= 0;
  mesh->vertices.reserve(static_cast<size_t>(element.count));
  if (has_normals) mesh->vertex_normals.reserve(static_cast<size_t>(element.count));
  std::vector<double> s(element.properties.size());
  std::vector<double> unused;
  for (uint64_t i = 0; i < element.count; ++i) {
    D3D_RETURN_IF_ERROR(ReadPlyItem(element, i, -1, reader, &s, &unused));
    const Eigen::Vector3d p(s[static_cast<size_t>(xyz[0])], s[static_cast<size_t>(xyz[1])],
                            s[static_cast<size_t>(xyz[2])]);
    if (!IsFinite(p))
      return Corrupt(Cat("ply: vertex ", i, " has a non-finite coordinate (", p.transpose(), ")"));
    mesh->vertices.push_back(p);
    if (!has_normals) continue;
    Eigen::Vector3d n(s[static_cast<size_t>(nxyz[0])], s[static_cast<size_t>(nxyz[1])],
                      s[static_cast<size_t>(nxyz[2])]);
    if (!IsFinite(n))
      return Corrupt(Cat("ply: vertex ", i, " has a non-finite normal (", n.transpose(), ")"));
    const double len = n.norm();
    mesh->vertex_normals.push_back(len > 0.0 ? Eigen::Vector3d(n / len) : n);
  }
  return Status::Ok();
}

// Where the per-face data sits in the face element (-1 when absent).
struct PlyFaceLayout {
  int indices = -1;
  std::array<int, 4> rgba = {-1, -1, -1, -1};
  int label = -1;
  int tooth_id = -1;

  bool has_color() const { return rgba[0] >= 0 && rgba[1] >= 0 && rgba[2] >= 0; }
};

uint8_t ColorChannel(double v, PlyType type) {
  if (IsFloat(type)) v *= 255.0;
  if (!(v > 0.0)) return 0;  // also NaN
  return static_cast<uint8_t>(std::lround(std::min(v, 255.0)));
}

// Fan-triangulates one face's index list, checking every index against the vertex count.
Status AppendPlyPolygon(const std::vector<double>& list, uint64_t face, uint64_t vertex_count,
                        std::vector<int>* corners, TriangleMesh* mesh) {
  if (list.size() < 3)
    return ParseError(Cat("ply: face ", face, " has ", list.size(), " vertices (need at least 3)"));
  corners->clear();
  for (double v : list) {
    if (!(v >= 0.0) || v != std::floor(v)) {
      return Corrupt(Cat("ply: face ", face, " index ", FormatValue(v), " is not a vertex index"));
    }
    if (v >= static_cast<double>(vertex_count)) {
      return Corrupt(
          Cat("ply: face ", face, " index ", FormatValue(v), " >= vertex count ", vertex_count));
    }
    corners->push_back(static_cast<int>(v));
  }
  AppendFan(*corners, mesh);
  return Status::Ok();
}

// Copies the per-face scalars of face `face` to its `triangles` new triangles.
Status AppendPlyFaceData(const PlyElement& element, const PlyFaceLayout& layout,
                         const std::vector<double>& s, uint64_t face, size_t triangles,
                         TriangleMesh* mesh) {
  if (layout.has_color()) {
    std::array<uint8_t, 4> rgba = {0, 0, 0, 255};
    for (size_t c = 0; c < 4; ++c) {
      const int p = layout.rgba[c];
      if (p >= 0)
        rgba[c] = ColorChannel(s[static_cast<size_t>(p)],
                               element.properties[static_cast<size_t>(p)].type);
    }
    mesh->face_colors.insert(mesh->face_colors.end(), triangles, rgba);
  }
  if (layout.label >= 0) {
    const double v = s[static_cast<size_t>(layout.label)];
    if (v != 0.0 && v != 1.0 && v != 2.0) {
      return Corrupt(Cat("ply: face ", face, " label ", FormatValue(v),
                         " is not 0 (unknown), 1 (gingiva) or 2 (tooth)"));
    }
    mesh->face_labels.insert(mesh->face_labels.end(), triangles,
                             static_cast<SurfaceLabel>(static_cast<int>(v)));
  }
  if (layout.tooth_id >= 0) {
    const double v = s[static_cast<size_t>(layout.tooth_id)];
    if (!(v >= 0.0 && v <= 255.0) || v != std::floor(v)) {
      return Corrupt(Cat("ply: face ", face, " tooth_id ", FormatValue(v), " is not in 0..255"));
    }
    mesh->face_tooth_ids.insert(mesh->face_tooth_ids.end(), triangles, static_cast<uint8_t>(v));
  }
  return Status::Ok();
}

Status ReadPlyFaces(const PlyElement& element, uint64_t vertex_count, PlyBodyReader* reader,
                    TriangleMesh* mesh) {
  PlyFaceLayout layout;
  layout.indices = element.Find({"vertex_indices", "vertex_index"}, true);
  if (layout.indices < 0)
    return ParseError("ply: face element has no 'vertex_indices' or 'vertex_index' list");
  layout.rgba = {element.Find({"red"}, false), element.Find({"green"}, false),
                 element.Find({"blue"}, false), element.Find({"alpha"}, false)};
  layout.label = element.Find({"label"}, false);
  layout.tooth_id = element.Find({"tooth_id"}, false);
  mesh->faces.reserve(static_cast<size_t>(element.count));
  std::vector<double> s(element.properties.size());
  std::vector<double> list;
  std::vector<int> corners;
  for (uint64_t i = 0; i < element.count; ++i) {
    D3D_RETURN_IF_ERROR(ReadPlyItem(element, i, layout.indices, reader, &s, &list));
    const size_t before = mesh->faces.size();
    D3D_RETURN_IF_ERROR(AppendPlyPolygon(list, i, vertex_count, &corners, mesh));
    D3D_RETURN_IF_ERROR(
        AppendPlyFaceData(element, layout, s, i, mesh->faces.size() - before, mesh));
  }
  return Status::Ok();
}

const PlyElement* FindElement(const PlyHeader& header, std::string_view name) {
  for (const PlyElement& e : header.elements) {
    if (e.name == name) return &e;
  }
  return nullptr;
}

Status ParsePly(std::string_view bytes, TriangleMesh* mesh) {
  PlyHeader header;
  D3D_RETURN_IF_ERROR(ParsePlyHeader(bytes, &header));
  const PlyElement* vertex = FindElement(header, "vertex");
  const PlyElement* face = FindElement(header, "face");
  if (vertex == nullptr) return ParseError("ply: no 'vertex' element");
  if (face == nullptr || face->count == 0)
    return ParseError("ply: no faces (a point cloud is not a mesh)");
  PlyBodyReader reader(bytes.substr(header.body_offset), header.encoding);
  for (const PlyElement& element : header.elements) {
    D3D_RETURN_IF_ERROR(CheckElementFits(element, header.encoding, reader.remaining()));
    if (&element == vertex) {
      D3D_RETURN_IF_ERROR(ReadPlyVertices(element, &reader, mesh));
    } else if (&element == face) {
      D3D_RETURN_IF_ERROR(ReadPlyFaces(element, vertex->count, &reader, mesh));
    } else {
      D3D_RETURN_IF_ERROR(SkipPlyElement(element, &reader));
    }
  }
  return Status::Ok();
}

// ------------------------------------------------------------------------------------------------
// STL

constexpr size_t kStlHeaderBytes = 84;
constexpr size_t kStlTriangleBytes = 50;

bool IsExactBinaryStl(std::string_view bytes) {
  if (bytes.size() < kStlHeaderBytes) return false;
  const uint64_t n = LoadScalar<uint32_t>(bytes.data() + 80, false);
  return bytes.size() == kStlHeaderBytes + kStlTriangleBytes * n;
}

bool StartsWithSolid(std::string_view bytes) { return StartsWithIgnoreCase(Trim(bytes), "solid"); }

Status ParseStlBinary(std::string_view bytes, TriangleMesh* mesh) {
  if (bytes.size() < kStlHeaderBytes) {
    return ParseError(
        Cat("stl: binary file of ", bytes.size(), " bytes is shorter than the 84-byte header"));
  }
  const uint64_t n = LoadScalar<uint32_t>(bytes.data() + 80, false);
  const uint64_t need = kStlHeaderBytes + kStlTriangleBytes * n;
  if (bytes.size() < need) {
    return ParseError(Cat("stl: binary header claims ", n, " triangles (", need,
                          " bytes) but the data has ", bytes.size(), " bytes (truncated)"));
  }
  // Whole triangles beyond the count: the count is wrong, and reading it would drop them silently.
  // Fewer surplus bytes than a triangle are tolerated (writers that pad the file).
  if (const uint64_t extra = (bytes.size() - need) / kStlTriangleBytes; extra > 0) {
    return ParseError(Cat("stl: binary header claims ", n, " triangles but the data holds ",
                          n + extra, " (", bytes.size() - need,
                          " bytes beyond them): the triangle count is wrong"));
  }
  if (n == 0) return ParseError("stl: no faces (binary header says 0 triangles)");
  VertexWelder welder(mesh);
  mesh->faces.reserve(static_cast<size_t>(n));
  for (uint64_t t = 0; t < n; ++t) {
    const char* p =
        bytes.data() + kStlHeaderBytes + kStlTriangleBytes * t + 12;  // after the normal
    Eigen::Vector3i face;
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector3d v;
      for (int a = 0; a < 3; ++a) v[a] = LoadScalar<float>(p + 4 * (3 * k + a), false);
      if (!IsFinite(v))
        return Corrupt(Cat("stl: triangle ", t, " has a non-finite vertex (", v.transpose(), ")"));
      face[k] = welder.Add(v);
    }
    mesh->faces.push_back(face);
  }
  return Status::Ok();
}

Status StlSyntaxError(const TextTokenizer& tok, std::string_view expected, std::string_view got) {
  return ParseError(Cat("stl: line ", tok.line(), ": expected ", expected, ", got ",
                        got.empty() ? std::string("end of data") : Quote(got)));
}

Status ExpectKeyword(TextTokenizer* tok, std::string_view keyword) {
  const std::string_view t = tok->Next();
  if (!EqualsIgnoreCase(t, keyword)) return StlSyntaxError(*tok, Cat("'", keyword, "'"), t);
  return Status::Ok();
}

Status ReadStlNumbers(TextTokenizer* tok, Eigen::Vector3d* v) {
  for (int a = 0; a < 3; ++a) {
    const std::string_view t = tok->Next();
    if (!ParseDouble(t, &(*v)[a])) return StlSyntaxError(*tok, "a number", t);
  }
  return Status::Ok();
}

// One "facet normal .. outer loop vertex .. (×3 or more) endloop endfacet" (after "facet").
Status ParseStlFacet(TextTokenizer* tok, VertexWelder* welder, std::vector<int>* corners,
                     TriangleMesh* mesh) {
  Eigen::Vector3d v;
  D3D_RETURN_IF_ERROR(ExpectKeyword(tok, "normal"));
  D3D_RETURN_IF_ERROR(ReadStlNumbers(tok, &v));  // the stored normal is not kept
  D3D_RETURN_IF_ERROR(ExpectKeyword(tok, "outer"));
  D3D_RETURN_IF_ERROR(ExpectKeyword(tok, "loop"));
  corners->clear();
  for (;;) {
    const std::string_view t = tok->Next();
    if (EqualsIgnoreCase(t, "endloop")) break;
    if (!EqualsIgnoreCase(t, "vertex")) return StlSyntaxError(*tok, "'vertex' or 'endloop'", t);
    D3D_RETURN_IF_ERROR(ReadStlNumbers(tok, &v));
    if (!IsFinite(v))
      return Corrupt(Cat("stl: line ", tok->line(), ": non-finite vertex (", v.transpose(), ")"));
    corners->push_back(welder->Add(v));
  }
  if (corners->size() < 3) {
    return ParseError(Cat("stl: line ", tok->line(), ": facet has ", corners->size(),
                          " vertices (need at least 3)"));
  }
  AppendFan(*corners, mesh);
  return ExpectKeyword(tok, "endfacet");
}

Status ParseStlAscii(std::string_view text, TriangleMesh* mesh) {
  TextTokenizer tok(text);
  D3D_RETURN_IF_ERROR(ExpectKeyword(&tok, "solid"));
  tok.SkipLine();  // the solid's name
  VertexWelder welder(mesh);
  std::vector<int> corners;
  for (;;) {
    const std::string_view t = tok.Next();
    if (t.empty()) break;  // a missing "endsolid" is tolerated
    if (EqualsIgnoreCase(t, "facet")) {
      D3D_RETURN_IF_ERROR(ParseStlFacet(&tok, &welder, &corners, mesh));
    } else if (EqualsIgnoreCase(t, "endsolid") || EqualsIgnoreCase(t, "solid")) {
      tok.SkipLine();  // the name; several solids in one file are merged
    } else {
      return StlSyntaxError(tok, "'facet' or 'endsolid'", t);
    }
  }
  if (mesh->faces.empty()) return ParseError("stl: no faces (no 'facet' in ascii STL)");
  return Status::Ok();
}

// Binary when the size is exactly 84 + 50·n (even if the header starts with "solid"), ascii when
// it starts with "solid", otherwise binary (which then reports what is wrong with the size).
Status ParseStl(std::string_view bytes, TriangleMesh* mesh) {
  if (IsExactBinaryStl(bytes)) return ParseStlBinary(bytes, mesh);
  if (StartsWithSolid(bytes)) return ParseStlAscii(bytes, mesh);
  return ParseStlBinary(bytes, mesh);
}

// ------------------------------------------------------------------------------------------------
// OBJ

bool IsObjKeyword(std::string_view t) {
  static constexpr std::array<std::string_view, 13> kKeywords = {
      "v", "vn", "vt", "vp", "f", "l", "p", "o", "g", "s", "usemtl", "mtllib", "cstype"};
  return std::find(kKeywords.begin(), kKeywords.end(), t) != kKeywords.end();
}

// Whether the first record that is not blank or a comment is an OBJ keyword.
bool LooksLikeObj(std::string_view bytes) {
  std::vector<std::string_view> tokens;
  size_t pos = 0;
  while (pos < bytes.size()) {
    size_t nl = bytes.find('\n', pos);
    if (nl == std::string_view::npos) nl = bytes.size();
    std::string_view line = bytes.substr(pos, nl - pos);
    pos = nl + 1;
    line = line.substr(0, line.find('#'));
    SplitWhitespace(line, &tokens);
    if (!tokens.empty()) return IsObjKeyword(tokens[0]);
  }
  return false;
}

// Reads OBJ records one line at a time into a mesh.
class ObjParser {
 public:
  Status Parse(std::string_view text, TriangleMesh* mesh) {
    mesh_ = mesh;
    size_t pos = 0;
    for (line_ = 1; pos < text.size(); ++line_) {
      size_t nl = text.find('\n', pos);
      if (nl == std::string_view::npos) nl = text.size();
      std::string_view line = text.substr(pos, nl - pos);
      pos = nl + 1;
      SplitWhitespace(line.substr(0, line.find('#')), &tokens_);
      if (tokens_.empty()) continue;
      D3D_RETURN_IF_ERROR(ParseRecord());
    }
    if (mesh_->faces.empty()) return ParseError("obj: no faces (no 'f' record)");
    FillVertexNormals();
    return Status::Ok();
  }

 private:
  Status Error(const std::string& what) const {
    return ParseError(Cat("obj: line ", line_, ": ", what));
  }

  Status ParseRecord() {
    const std::string_view keyword = tokens_[0];
    if (keyword == "v" || keyword == "vn") {
      Eigen::Vector3d v;
      D3D_RETURN_IF_ERROR(ReadVector(&v));
      if (keyword == "vn") {
        normals_.push_back(v);
      } else {
        mesh_->vertices.push_back(v);
        normal_of_vertex_.push_back(-1);
      }
      return Status::Ok();
    }
    if (keyword == "f") return ParseFace();
    return Status::Ok();  // vt, g, o, s, usemtl, mtllib, l, ...: not needed for the mesh
  }

  Status ReadVector(Eigen::Vector3d* v) const {
    if (tokens_.size() < 4) return Error(Cat("'", tokens_[0], "' needs 3 numbers"));
    for (int a = 0; a < 3; ++a) {
      if (!ParseDouble(tokens_[static_cast<size_t>(a) + 1], &(*v)[a])) {
        return Error(Cat(Quote(tokens_[static_cast<size_t>(a) + 1]), " is not a number"));
      }
    }
    if (!IsFinite(*v))
      return Corrupt(
          Cat("obj: line ", line_, ": non-finite '", tokens_[0], "' (", v->transpose(), ")"));
    return Status::Ok();
  }

  // 1-based (or negative, relative to the `count` defined so far) index → 0-based.
  Status ResolveIndex(std::string_view token, size_t count, const char* what, int* index) const {
    int64_t i = 0;
    if (!ParseInt64(token, &i))
      return Error(Cat(what, " index ", Quote(token), " is not an integer"));
    const auto n = static_cast<int64_t>(count);
    if (i == 0)
      return Corrupt(Cat("obj: line ", line_, ": ", what, " index 0 (OBJ indices start at 1)"));
    if (i > n)
      return Corrupt(Cat("obj: line ", line_, ": ", what, " index ", i, " > ", what, " count ", n));
    if (i < -n)
      return Corrupt(
          Cat("obj: line ", line_, ": ", what, " index ", i, " reaches before the first ", what));
    *index = static_cast<int>(i > 0 ? i - 1 : n + i);
    return Status::Ok();
  }

  // One corner: "v", "v/vt", "v//vn" or "v/vt/vn".
  Status ParseCorner(std::string_view token, int* vertex) {
    const size_t slash1 = token.find('/');
    D3D_RETURN_IF_ERROR(
        ResolveIndex(token.substr(0, slash1), mesh_->vertices.size(), "vertex", vertex));
    if (slash1 == std::string_view::npos) return Status::Ok();
    const size_t slash2 = token.find('/', slash1 + 1);
    if (slash2 == std::string_view::npos || slash2 + 1 == token.size())
      return Status::Ok();  // v/vt, v/vt/
    int normal = 0;
    D3D_RETURN_IF_ERROR(ResolveIndex(token.substr(slash2 + 1), normals_.size(), "normal", &normal));
    int& slot = normal_of_vertex_[static_cast<size_t>(*vertex)];
    if (slot < 0) slot = normal;
    return Status::Ok();
  }

  Status ParseFace() {
    if (tokens_.size() < 4)
      return Error(Cat("face has ", tokens_.size() - 1, " corners (need at least 3)"));
    corners_.resize(tokens_.size() - 1);
    for (size_t i = 1; i < tokens_.size(); ++i)
      D3D_RETURN_IF_ERROR(ParseCorner(tokens_[i], &corners_[i - 1]));
    AppendFan(corners_, mesh_);
    return Status::Ok();
  }

  // Vertex normals only when every vertex got one from a face corner.
  void FillVertexNormals() {
    if (normals_.empty()) return;
    if (std::find(normal_of_vertex_.begin(), normal_of_vertex_.end(), -1) !=
        normal_of_vertex_.end())
      return;
    mesh_->vertex_normals.reserve(mesh_->vertices.size());
    for (int n : normal_of_vertex_) {
      const Eigen::Vector3d& v = normals_[static_cast<size_t>(n)];
      const double len = v.norm();
      mesh_->vertex_normals.push_back(len > 0.0 ? Eigen::Vector3d(v / len) : v);
    }
  }

  TriangleMesh* mesh_ = nullptr;
  int line_ = 0;
  std::vector<std::string_view> tokens_;
  std::vector<int> corners_;
  std::vector<Eigen::Vector3d> normals_;
  std::vector<int> normal_of_vertex_;  // index into normals_, -1 if none yet
};

// ------------------------------------------------------------------------------------------------
// Dispatch

MeshFormat FormatFromExtension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& c : ext) c = ToLower(c);
  if (ext == ".ply") return MeshFormat::kPly;
  if (ext == ".stl") return MeshFormat::kStl;
  if (ext == ".obj") return MeshFormat::kObj;
  return MeshFormat::kAuto;
}

Status ParseAs(std::string_view bytes, MeshFormat format, TriangleMesh* mesh) {
  switch (format) {
    case MeshFormat::kPly:
      return ParsePly(bytes, mesh);
    case MeshFormat::kStl:
      return ParseStl(bytes, mesh);
    case MeshFormat::kObj: {
      ObjParser parser;
      return parser.Parse(bytes, mesh);
    }
    case MeshFormat::kAuto:
      break;
  }
  return ParseError(Cat("mesh: unknown format (not PLY, STL or OBJ), data starts with ",
                        Quote(bytes.substr(0, 16))));
}

// Parses `bytes` into *out without throwing; *out is replaced only on success.
Status LoadNoThrow(std::string_view bytes, MeshFormat format, TriangleMesh* out) {
  try {
    if (bytes.empty()) return ParseError("mesh: empty data");
    if (format == MeshFormat::kAuto) format = DetectMeshFormat(bytes);
    TriangleMesh mesh;
    D3D_RETURN_IF_ERROR(ParseAs(bytes, format, &mesh));
    mesh.Check();  // a failure here is a bug of the parser: reported as INTERNAL below
    *out = std::move(mesh);
    return Status::Ok();
  } catch (const std::bad_alloc&) {
    return {StatusCode::kInternal, "mesh: out of memory while loading"};
  } catch (const std::exception& e) {
    return {StatusCode::kInternal, Cat("mesh: unexpected error while loading: ", e.what())};
  } catch (...) {
    return {StatusCode::kInternal, "mesh: unexpected non-standard exception while loading"};
  }
}

Status ReadWholeFile(const std::string& path, std::string* bytes) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return NotFound(Cat("mesh: no such file '", path, "'"));
  if (std::filesystem::is_directory(path, ec))
    return IoError(Cat("mesh: '", path, "' is a directory"));
  std::ifstream f(path, std::ios::binary);
  if (!f) return IoError(Cat("mesh: cannot open '", path, "' for reading"));
  std::ostringstream ss;
  ss << f.rdbuf();
  if (f.bad()) return IoError(Cat("mesh: read error on '", path, "'"));
  *bytes = std::move(ss).str();
  return Status::Ok();
}

// ------------------------------------------------------------------------------------------------
// Writing

Status ValidateForSave(const TriangleMesh& mesh) {
  try {
    mesh.Check();
  } catch (const std::exception& e) {
    return InvalidArgument(Cat("mesh fails Check: ", e.what()));
  }
  if (mesh.faces.empty()) return InvalidArgument("mesh has no faces");
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    if (!FitsFloat(mesh.vertices[i]))
      return InvalidArgument(Cat("vertex ", i, " is not a finite float"));
  }
  for (size_t i = 0; i < mesh.vertex_normals.size(); ++i) {
    if (!FitsFloat(mesh.vertex_normals[i]))
      return InvalidArgument(Cat("normal ", i, " is not a finite float"));
  }
  return Status::Ok();
}

std::string PlyHeaderText(const TriangleMesh& mesh, const char* format) {
  std::ostringstream h;
  h << "ply\nformat " << format << " 1.0\ncomment d3dscan mesh, units mm\n";
  h << "element vertex " << mesh.vertices.size()
    << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (!mesh.vertex_normals.empty())
    h << "property float nx\nproperty float ny\nproperty float nz\n";
  h << "element face " << mesh.faces.size() << "\nproperty list uchar int vertex_indices\n";
  if (!mesh.face_colors.empty()) {
    h << "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n";
  }
  if (!mesh.face_labels.empty()) h << "property uchar label\n";
  if (!mesh.face_tooth_ids.empty()) h << "property uchar tooth_id\n";
  h << "end_header\n";
  return h.str();
}

void AppendFloats(std::string* out, const Eigen::Vector3d& v) {
  for (int a = 0; a < 3; ++a) AppendLittleEndian(out, static_cast<float>(v[a]));
}

// The per-face uchar values (colour, label, tooth id) in header order.
std::vector<uint8_t> FaceBytes(const TriangleMesh& mesh, size_t f) {
  std::vector<uint8_t> b;
  if (!mesh.face_colors.empty()) b.assign(mesh.face_colors[f].begin(), mesh.face_colors[f].end());
  if (!mesh.face_labels.empty()) b.push_back(static_cast<uint8_t>(mesh.face_labels[f]));
  if (!mesh.face_tooth_ids.empty()) b.push_back(mesh.face_tooth_ids[f]);
  return b;
}

std::string EncodePlyBinary(const TriangleMesh& mesh) {
  std::string out = PlyHeaderText(mesh, "binary_little_endian");
  out.reserve(out.size() + mesh.vertices.size() * 24 + mesh.faces.size() * 19);
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    AppendFloats(&out, mesh.vertices[i]);
    if (!mesh.vertex_normals.empty()) AppendFloats(&out, mesh.vertex_normals[i]);
  }
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    out.push_back(3);
    for (int k = 0; k < 3; ++k) AppendLittleEndian(&out, static_cast<int32_t>(mesh.faces[f][k]));
    for (uint8_t b : FaceBytes(mesh, f)) out.push_back(static_cast<char>(b));
  }
  return out;
}

// Shortest decimal text that reads back as the same float, each followed by a space.
void AppendAsciiFloats(std::string* out, const Eigen::Vector3d& v) {
  for (int a = 0; a < 3; ++a) {
    std::array<char, 32> buf;
    const auto [end, ec] =
        std::to_chars(buf.data(), buf.data() + buf.size(), static_cast<float>(v[a]));
    out->append(buf.data(), ec == std::errc() ? end : buf.data());
    out->push_back(' ');
  }
}

std::string EncodePlyAscii(const TriangleMesh& mesh) {
  std::string out = PlyHeaderText(mesh, "ascii");
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    AppendAsciiFloats(&out, mesh.vertices[i]);
    if (!mesh.vertex_normals.empty()) AppendAsciiFloats(&out, mesh.vertex_normals[i]);
    out.back() = '\n';  // replaces the last separator
  }
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    const Eigen::Vector3i& t = mesh.faces[f];
    out += Cat("3 ", t[0], ' ', t[1], ' ', t[2]);
    for (uint8_t b : FaceBytes(mesh, f)) out += Cat(' ', static_cast<int>(b));
    out += '\n';
  }
  return out;
}

std::string EncodeStlBinary(const TriangleMesh& mesh) {
  std::string out(80, ' ');
  const std::string_view title = "d3dscan binary STL, units mm";
  std::copy(title.begin(), title.end(), out.begin());
  AppendLittleEndian(&out, static_cast<uint32_t>(mesh.faces.size()));
  out.reserve(out.size() + mesh.faces.size() * kStlTriangleBytes);
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    AppendFloats(&out, mesh.FaceNormal(static_cast<int>(f)));
    for (int k = 0; k < 3; ++k)
      AppendFloats(&out, mesh.vertices[static_cast<size_t>(mesh.faces[f][k])]);
    AppendLittleEndian(&out, static_cast<uint16_t>(0));
  }
  return out;
}

Status WriteWholeFile(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) return IoError(Cat("mesh: cannot open '", path, "' for writing"));
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  f.close();
  if (!f) return IoError(Cat("mesh: write error on '", path, "'"));
  return Status::Ok();
}

// Validates, encodes and writes a mesh without throwing.
template <typename Encoder>
Status SaveWith(const std::string& path, const TriangleMesh& mesh, const char* what,
                Encoder encode) {
  try {
    D3D_RETURN_IF_ERROR(Prefixed(Cat(what, " '", path, "': "), ValidateForSave(mesh)));
    if (mesh.faces.size() > std::numeric_limits<uint32_t>::max()) {
      return InvalidArgument(Cat(what, " '", path, "': too many faces"));
    }
    return WriteWholeFile(path, encode(mesh));
  } catch (const std::exception& e) {
    return {StatusCode::kInternal, Cat(what, " '", path, "': ", e.what())};
  }
}

}  // namespace

const char* MeshFormatName(MeshFormat format) {
  switch (format) {
    case MeshFormat::kAuto:
      return "auto";
    case MeshFormat::kPly:
      return "PLY";
    case MeshFormat::kStl:
      return "STL";
    case MeshFormat::kObj:
      return "OBJ";
  }
  return "unknown";
}

MeshFormat DetectMeshFormat(std::string_view bytes) {
  if (IsPlyMagic(bytes)) return MeshFormat::kPly;
  if (IsExactBinaryStl(bytes) || StartsWithSolid(bytes)) return MeshFormat::kStl;
  if (LooksLikeObj(bytes)) return MeshFormat::kObj;
  return MeshFormat::kAuto;
}

Status LoadMesh(const std::string& path, TriangleMesh* out) {
  if (out == nullptr) return InvalidArgument("LoadMesh: null output mesh");
  std::string bytes;
  try {
    D3D_RETURN_IF_ERROR(ReadWholeFile(path, &bytes));
  } catch (const std::exception& e) {
    return IoError(Cat("mesh: cannot read '", path, "': ", e.what()));
  }
  if (bytes.empty()) return ParseError(Cat(path, ": mesh: empty file"));
  MeshFormat format = DetectMeshFormat(bytes);
  if (format == MeshFormat::kAuto) format = FormatFromExtension(path);
  return Prefixed(path + ": ", LoadNoThrow(bytes, format, out));
}

Status LoadMeshFromMemory(const std::string& bytes, MeshFormat hint, TriangleMesh* out) {
  if (out == nullptr) return InvalidArgument("LoadMeshFromMemory: null output mesh");
  return LoadNoThrow(bytes, hint, out);
}

void LabelFacesFromColors(TriangleMesh* mesh) {
  if (mesh == nullptr || mesh->face_colors.empty()) return;
  constexpr int kMinToothSaturation = 40;
  mesh->face_labels.resize(mesh->face_colors.size());
  for (size_t f = 0; f < mesh->face_colors.size(); ++f) {
    const std::array<uint8_t, 4>& c = mesh->face_colors[f];
    const int hi = std::max({c[0], c[1], c[2]});
    const int lo = std::min({c[0], c[1], c[2]});
    mesh->face_labels[f] =
        (hi - lo < kMinToothSaturation) ? SurfaceLabel::kGingiva : SurfaceLabel::kTooth;
  }
  mesh->face_tooth_ids.assign(mesh->face_colors.size(), 0);
}

Status SavePlyBinary(const std::string& path, const TriangleMesh& mesh) {
  return SaveWith(path, mesh, "SavePlyBinary", EncodePlyBinary);
}

Status SavePlyAscii(const std::string& path, const TriangleMesh& mesh) {
  return SaveWith(path, mesh, "SavePlyAscii", EncodePlyAscii);
}

Status SaveStlBinary(const std::string& path, const TriangleMesh& mesh) {
  return SaveWith(path, mesh, "SaveStlBinary", EncodeStlBinary);
}

}  // namespace d3d
