#include "common/mesh/mesh_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <random>
#include <sstream>
#include <string>

#include "common/mesh/mesh_io_fuzz.h"

namespace d3d {
namespace {

using ::testing::HasSubstr;

std::string TempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() /
          ("d3d_mesh_io_" + std::to_string(getpid()) + "_" + name))
      .string();
}

void WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(f.good()) << path;
}

// Typed values appended in a chosen byte order, to write binary PLY/STL by hand.
class ByteWriter {
 public:
  explicit ByteWriter(bool big_endian) : big_(big_endian) {}
  template <typename T>
  ByteWriter& operator<<(T v) {
    std::array<char, sizeof(T)> b;
    std::memcpy(b.data(), &v, sizeof(T));
    if (big_ != (std::endian::native == std::endian::big)) std::reverse(b.begin(), b.end());
    bytes.append(b.data(), b.size());
    return *this;
  }
  std::string bytes;

 private:
  bool big_;
};

// ---------------------------------------------------------------------------------------------
// A PLY with properties in odd order and of odd types, lists inside the vertex element, and
// unknown elements before and after the faces; written as ascii or binary (either endianness).

std::string OddPlyHeader(const std::string& format) {
  return "ply\n"
         "format " +
         format +
         " 1.0\n"
         "comment odd property order and types\n"
         "element vertex 4\n"
         "property uchar quality\n"
         "property double z\n"
         "property list uchar float extra\n"
         "property float32 y\n"
         "property int8 x\n"
         "property float nz\n"
         "property float nx\n"
         "property float ny\n"
         "element edge 2\n"
         "property int vertex1\n"
         "property int vertex2\n"
         "property list ushort int stuff\n"
         "element face 2\n"
         "property uchar green\n"
         "property list uint8 uint32 vertex_index\n"
         "property uchar red\n"
         "property uchar blue\n"
         "property int label\n"
         "element material 1\n"
         "property uchar ambient_red\n"
         "end_header\n";
}

std::string OddPlyAscii() {
  return OddPlyHeader("ascii") +
         "7 0.5 2 1.5 2.5 0 0 2 0 0\n"
         "7 0.5 0 0 1 2 0 0\n"
         "7 0.5 1 -3 1.5 1 2 0 0\n"
         "7 -0.25 0 1.5 0 2 0 0\n"
         "0 1 0\n"
         "1 2 3 5 6 7\n"
         "255 4 0 1 2 3 10 0 2\n"
         "200 3 0 2 1 200 200 1\n"
         "9\n";
}

std::string OddPlyBinary(bool big_endian) {
  ByteWriter w(big_endian);
  struct V {
    double z;
    std::vector<float> extra;
    float y;
    int8_t x;
  };
  const V vs[4] = {
      {0.5, {1.5f, 2.5f}, 0.f, 0}, {0.5, {}, 0.f, 1}, {0.5, {-3.f}, 1.5f, 1}, {-0.25, {}, 1.5f, 0}};
  for (const V& v : vs) {
    w << uint8_t{7} << v.z << static_cast<uint8_t>(v.extra.size());
    for (float e : v.extra) w << e;
    w << v.y << v.x << 2.f << 0.f << 0.f;
  }
  w << int32_t{0} << int32_t{1} << uint16_t{0};
  w << int32_t{1} << int32_t{2} << uint16_t{3} << int32_t{5} << int32_t{6} << int32_t{7};
  w << uint8_t{255} << uint8_t{4} << uint32_t{0} << uint32_t{1} << uint32_t{2} << uint32_t{3};
  w << uint8_t{10} << uint8_t{0} << int32_t{2};
  w << uint8_t{200} << uint8_t{3} << uint32_t{0} << uint32_t{2} << uint32_t{1};
  w << uint8_t{200} << uint8_t{200} << int32_t{1};
  w << uint8_t{9};
  return OddPlyHeader(big_endian ? "binary_big_endian" : "binary_little_endian") + w.bytes;
}

void ExpectOddMesh(const TriangleMesh& m) {
  ASSERT_EQ(m.vertices.size(), 4u);
  EXPECT_EQ(m.vertices[0], Eigen::Vector3d(0, 0, 0.5));
  EXPECT_EQ(m.vertices[1], Eigen::Vector3d(1, 0, 0.5));
  EXPECT_EQ(m.vertices[2], Eigen::Vector3d(1, 1.5, 0.5));
  EXPECT_EQ(m.vertices[3], Eigen::Vector3d(0, 1.5, -0.25));
  ASSERT_EQ(m.vertex_normals.size(), 4u);
  EXPECT_EQ(m.vertex_normals[2], Eigen::Vector3d(0, 0, 1));  // (0,0,2) normalised
  ASSERT_EQ(m.faces.size(), 3u);                             // the quad became two triangles
  EXPECT_EQ(m.faces[0], Eigen::Vector3i(0, 1, 2));
  EXPECT_EQ(m.faces[1], Eigen::Vector3i(0, 2, 3));
  EXPECT_EQ(m.faces[2], Eigen::Vector3i(0, 2, 1));
  ASSERT_EQ(m.face_colors.size(), 3u);
  EXPECT_EQ(m.face_colors[0], (std::array<uint8_t, 4>{10, 255, 0, 255}));  // alpha 255 when absent
  EXPECT_EQ(m.face_colors[1], (std::array<uint8_t, 4>{10, 255, 0, 255}));
  EXPECT_EQ(m.face_colors[2], (std::array<uint8_t, 4>{200, 200, 200, 255}));
  EXPECT_EQ(m.face_labels, (std::vector<SurfaceLabel>{SurfaceLabel::kTooth, SurfaceLabel::kTooth,
                                                      SurfaceLabel::kGingiva}));
  EXPECT_TRUE(m.face_tooth_ids.empty());
  EXPECT_NO_THROW(m.Check());
}

TEST(MeshIoPly, AsciiOddLayout) {
  TriangleMesh m;
  const Status s = LoadMeshFromMemory(OddPlyAscii(), MeshFormat::kAuto, &m);
  ASSERT_TRUE(s.ok()) << s.ToString();
  ExpectOddMesh(m);
}

TEST(MeshIoPly, BinaryLittleEndianOddLayout) {
  TriangleMesh m;
  const Status s = LoadMeshFromMemory(OddPlyBinary(false), MeshFormat::kAuto, &m);
  ASSERT_TRUE(s.ok()) << s.ToString();
  ExpectOddMesh(m);
}

TEST(MeshIoPly, BinaryBigEndianOddLayout) {
  TriangleMesh m;
  const Status s = LoadMeshFromMemory(OddPlyBinary(true), MeshFormat::kPly, &m);
  ASSERT_TRUE(s.ok()) << s.ToString();
  ExpectOddMesh(m);
}

TEST(MeshIoPly, AllTypeNamesAndFloatColours) {
  // Every PLY type name, both spellings; CRLF line ends; float colours in 0..1.
  std::string ply =
      "ply\r\nformat ascii 1.0\r\nelement vertex 3\r\n"
      "property char a\r\nproperty int8 b\r\nproperty uchar c\r\nproperty uint8 d\r\n"
      "property short e\r\nproperty int16 f\r\nproperty ushort g\r\nproperty uint16 h\r\n"
      "property int i\r\nproperty int32 j\r\nproperty uint k\r\nproperty uint32 l\r\n"
      "property float32 x\r\nproperty float64 y\r\nproperty double z\r\n"
      "element face 1\r\nproperty list int short vertex_indices\r\n"
      "property float red\r\nproperty double green\r\nproperty float blue\r\nproperty float "
      "alpha\r\n"
      "property uchar tooth_id\r\nend_header\r\n";
  for (int v = 0; v < 3; ++v) {
    ply += "-128 127 255 0 -32768 32767 65535 0 -2147483648 2147483647 4294967295 0 ";
    ply += std::to_string(v) + " 1e-3 +2.5\r\n";
  }
  ply += "3 0 1 2 1.0 0.5 0 0.2 47\r\n";
  TriangleMesh m;
  const Status s = LoadMeshFromMemory(ply, MeshFormat::kAuto, &m);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(m.vertices[2], Eigen::Vector3d(2, 1e-3, 2.5));
  EXPECT_TRUE(m.vertex_normals.empty());
  EXPECT_EQ(m.face_colors[0], (std::array<uint8_t, 4>{255, 128, 0, 51}));
  EXPECT_EQ(m.face_tooth_ids, std::vector<uint8_t>{47});
  EXPECT_TRUE(m.face_labels.empty());
}

TEST(MeshIoPly, PolygonsAreFanTriangulated) {
  const std::string ply =
      "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float "
      "z\n"
      "element face 1\nproperty list uchar int vertex_indices\nproperty uchar label\nend_header\n"
      "0 0 0\n1 0 0\n2 1 0\n1 2 0\n0 2 0\n-1 1 0\n6 0 1 2 3 4 5 1\n";
  TriangleMesh m;
  ASSERT_TRUE(LoadMeshFromMemory(ply, MeshFormat::kAuto, &m).ok());
  ASSERT_EQ(m.faces.size(), 4u);
  EXPECT_EQ(m.faces[3], Eigen::Vector3i(0, 4, 5));
  EXPECT_EQ(m.face_labels, std::vector<SurfaceLabel>(4, SurfaceLabel::kGingiva));
  EXPECT_TRUE(m.face_colors.empty());
}

// ---------------------------------------------------------------------------------------------
// Round trips through the writers

TriangleMesh DecoratedCube() {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i)
    m.vertices.emplace_back(10.25 * (i & 1), -3.5 + ((i >> 1) & 1), 0.125 * ((i >> 2) & 1));
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.faces.emplace_back(q[0], q[1], q[2]);
    m.faces.emplace_back(q[0], q[2], q[3]);
  }
  m.ComputeVertexNormals();
  for (size_t f = 0; f < m.faces.size(); ++f) {
    m.face_colors.push_back({static_cast<uint8_t>(20 * f), 255, static_cast<uint8_t>(f),
                             static_cast<uint8_t>(200 + f)});
    m.face_labels.push_back(f % 3 == 0 ? SurfaceLabel::kGingiva : SurfaceLabel::kTooth);
    m.face_tooth_ids.push_back(static_cast<uint8_t>(11 + f));
  }
  return m;
}

void ExpectSameMesh(const TriangleMesh& a, const TriangleMesh& b) {
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  for (size_t i = 0; i < a.vertices.size(); ++i)
    EXPECT_TRUE(a.vertices[i].isApprox(b.vertices[i], 1e-6)) << i;
  ASSERT_EQ(a.vertex_normals.size(), b.vertex_normals.size());
  for (size_t i = 0; i < a.vertex_normals.size(); ++i) {
    EXPECT_TRUE(a.vertex_normals[i].isApprox(b.vertex_normals[i], 1e-6)) << i;
  }
  EXPECT_EQ(a.faces, b.faces);
  EXPECT_EQ(a.face_colors, b.face_colors);
  EXPECT_EQ(a.face_labels, b.face_labels);
  EXPECT_EQ(a.face_tooth_ids, b.face_tooth_ids);
}

TEST(MeshIoRoundTrip, PlyBinary) {
  const TriangleMesh cube = DecoratedCube();
  const std::string path = TempPath("cube_bin.ply");
  ASSERT_TRUE(SavePlyBinary(path, cube).ok());
  TriangleMesh back;
  const Status s = LoadMesh(path, &back);
  ASSERT_TRUE(s.ok()) << s.ToString();
  ExpectSameMesh(cube, back);
  std::filesystem::remove(path);
}

TEST(MeshIoRoundTrip, PlyAsciiIsFloatExact) {
  TriangleMesh cube = DecoratedCube();
  cube.vertices[3] = Eigen::Vector3d(0.1, 1.0 / 3.0, -12345.678);
  const std::string path = TempPath("cube_ascii.ply");
  ASSERT_TRUE(SavePlyAscii(path, cube).ok());
  TriangleMesh back;
  const Status s = LoadMesh(path, &back);
  ASSERT_TRUE(s.ok()) << s.ToString();
  ExpectSameMesh(cube, back);
  for (int a = 0; a < 3; ++a)
    EXPECT_EQ(back.vertices[3][a], static_cast<double>(static_cast<float>(cube.vertices[3][a])));
  std::filesystem::remove(path);
}

TEST(MeshIoRoundTrip, PlyWithoutOptionalArrays) {
  TriangleMesh cube = DecoratedCube();
  cube.vertex_normals.clear();
  cube.face_colors.clear();
  cube.face_tooth_ids.clear();
  const std::string path = TempPath("cube_plain.ply");
  ASSERT_TRUE(SavePlyBinary(path, cube).ok());
  TriangleMesh back;
  ASSERT_TRUE(LoadMesh(path, &back).ok());
  ExpectSameMesh(cube, back);
  std::filesystem::remove(path);
}

// Face corners as positions, to compare meshes whose vertex order differs.
std::vector<std::array<double, 9>> Corners(const TriangleMesh& m) {
  std::vector<std::array<double, 9>> out;
  for (const Eigen::Vector3i& f : m.faces) {
    std::array<double, 9> c{};
    for (int k = 0; k < 3; ++k) {
      for (int a = 0; a < 3; ++a)
        c[static_cast<size_t>(3 * k + a)] = static_cast<float>(m.vertices[f[k]][a]);
    }
    out.push_back(c);
  }
  return out;
}

TEST(MeshIoRoundTrip, StlBinaryWeldsCorners) {
  const TriangleMesh cube = DecoratedCube();
  const std::string path = TempPath("cube.stl");
  ASSERT_TRUE(SaveStlBinary(path, cube).ok());
  EXPECT_EQ(std::filesystem::file_size(path), 84u + 50u * 12u);
  TriangleMesh back;
  const Status s = LoadMesh(path, &back);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(back.vertices.size(), 8u);  // 36 corners welded back to the 8 corners
  EXPECT_EQ(Corners(back), Corners(cube));
  EXPECT_NEAR(back.SurfaceArea(), cube.SurfaceArea(), 1e-4);
  EXPECT_TRUE(back.face_colors.empty());
  std::filesystem::remove(path);
}

TEST(MeshIoStl, AsciiWithPolygonAndTwoSolids) {
  const std::string stl =
      "  solid my part\n"
      "facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 1 1 0\n "
      "endloop\nendfacet\n"
      "FACET NORMAL 0 0 1\n OUTER LOOP\n  VERTEX 0 0 0\n  VERTEX 1 1 0\n  VERTEX 0 1 0\n "
      "ENDLOOP\nENDFACET\n"
      "endsolid my part\n"
      "solid second\n"
      "facet normal 0 0 0\n outer loop\n vertex 0 0 0\n vertex 0 -1 0\n vertex -1 -1 0\n vertex -1 "
      "0 0\n endloop\n"
      "endfacet\nendsolid\n";
  TriangleMesh m;
  const Status s = LoadMeshFromMemory(stl, MeshFormat::kAuto, &m);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(m.faces.size(), 4u);
  EXPECT_EQ(m.vertices.size(), 7u);  // (0,0,0) and (1,1,0) shared
  EXPECT_EQ(m.faces[1], Eigen::Vector3i(0, 2, 3));
  EXPECT_NEAR(m.SurfaceArea(), 2.0, 1e-12);
}

std::string BinaryStl(const std::string& header80, uint32_t n) {
  ByteWriter w(false);
  std::string header = header80;
  header.resize(80, ' ');
  w.bytes = header;
  w << n;
  for (uint32_t t = 0; t < n; ++t) {
    w << 0.f << 0.f << 1.f;
    w << 0.f << 0.f << 0.f << 1.f << 0.f << 0.f << static_cast<float>(t % 2) << 1.f << 0.f;
    w << uint16_t{0};
  }
  return w.bytes;
}

TEST(MeshIoStl, BinaryWhoseHeaderSaysSolidLoadsAsBinary) {
  const std::string stl = BinaryStl("solid exported by a CAD tool that writes binary anyway", 2);
  EXPECT_EQ(DetectMeshFormat(stl), MeshFormat::kStl);
  TriangleMesh m;
  const Status s = LoadMeshFromMemory(stl, MeshFormat::kAuto, &m);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(m.faces.size(), 2u);
  EXPECT_EQ(m.vertices.size(), 4u);
  // The same through a file with the .stl extension.
  const std::string path = TempPath("solid_header.stl");
  WriteFile(path, stl);
  TriangleMesh f;
  ASSERT_TRUE(LoadMesh(path, &f).ok());
  EXPECT_EQ(f.faces.size(), 2u);
  std::filesystem::remove(path);
}

// ---------------------------------------------------------------------------------------------
// OBJ

TEST(MeshIoObj, AllFaceFormsNegativeIndicesAndQuads) {
  const std::string obj =
      "# a comment\nmtllib parts.mtl\no square\n"
      "v 0 0 0\nv 1 0 0\nv 1 1 0 1.0\nv 0 1 0 0.5 0.5 0.5\n"
      "vt 0 0\nvt 1 0\nvt 1 1\n"
      "vn 0 0 1\nvn 0 0 2\n"
      "g group\nusemtl skin\ns off\n"
      "f 1 2 3\n"
      "f 1/1 3/3 4/2   # trailing comment\n"
      "f -4//1 -3//2 -2//1\n"
      "f 1/1/1 2/2/1 3/3/1 4/1/1\n"
      "f -1 -2 -3\n"
      "l 1 2\n";
  TriangleMesh m;
  const Status s = LoadMeshFromMemory(obj, MeshFormat::kAuto, &m);
  ASSERT_TRUE(s.ok()) << s.ToString();
  ASSERT_EQ(m.vertices.size(), 4u);
  const std::vector<Eigen::Vector3i> expected = {{0, 1, 2}, {0, 2, 3}, {0, 1, 2},
                                                 {0, 1, 2}, {0, 2, 3}, {3, 2, 1}};
  EXPECT_EQ(m.faces, expected);
  ASSERT_EQ(m.vertex_normals.size(), 4u);  // every vertex got a normal from some corner
  for (const Eigen::Vector3d& n : m.vertex_normals) EXPECT_EQ(n, Eigen::Vector3d(0, 0, 1));
}

TEST(MeshIoObj, NoNormalsWhenSomeVertexLacksOne) {
  const std::string obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nvn 0 0 1\nf 1//1 2//1 3//1\n";
  TriangleMesh m;
  ASSERT_TRUE(LoadMeshFromMemory(obj, MeshFormat::kObj, &m).ok());
  EXPECT_EQ(m.faces.size(), 1u);
  EXPECT_TRUE(m.vertex_normals.empty());
}

TEST(MeshIoDispatch, ContentFirstThenExtension) {
  // PLY content under a .stl name loads as PLY.
  const std::string as_stl = TempPath("really_a_ply.stl");
  WriteFile(as_stl, OddPlyAscii());
  TriangleMesh m;
  ASSERT_TRUE(LoadMesh(as_stl, &m).ok());
  EXPECT_EQ(m.faces.size(), 3u);
  // An OBJ whose first record is not a known keyword is recognised by its extension (any case).
  const std::string obj_path = TempPath("odd_start.OBJ");
  WriteFile(obj_path, "# exporter\nbevel off\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  EXPECT_EQ(DetectMeshFormat("bevel off\nv 0 0 0\n"), MeshFormat::kAuto);
  TriangleMesh o;
  const Status s = LoadMesh(obj_path, &o);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(o.faces.size(), 1u);
  std::filesystem::remove(as_stl);
  std::filesystem::remove(obj_path);
}

// ---------------------------------------------------------------------------------------------
// Refusals

// Loads `bytes`, expects failure with `code` and a message containing `needle`; the output mesh
// must be left untouched.
void ExpectRefused(const std::string& bytes, MeshFormat format, StatusCode code,
                   const std::string& needle) {
  TriangleMesh m;
  m.vertices = {{7, 7, 7}};
  const Status s = LoadMeshFromMemory(bytes, format, &m);
  ASSERT_FALSE(s.ok()) << "loaded although expected " << StatusCodeName(code) << " / " << needle;
  EXPECT_EQ(s.code(), code) << s.ToString();
  EXPECT_THAT(s.message(), HasSubstr(needle));
  EXPECT_EQ(m.vertices.size(), 1u);
  EXPECT_TRUE(m.faces.empty());
}

const std::string kTriPlyHeader =
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float "
    "z\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n";

TEST(MeshIoRefuse, EmptyData) {
  for (MeshFormat f : {MeshFormat::kAuto, MeshFormat::kPly, MeshFormat::kStl, MeshFormat::kObj}) {
    ExpectRefused("", f, StatusCode::kParseError, "empty");
  }
  const std::string path = TempPath("empty.ply");
  WriteFile(path, "");
  TriangleMesh m;
  const Status s = LoadMesh(path, &m);
  EXPECT_EQ(s.code(), StatusCode::kParseError);
  EXPECT_THAT(s.message(), HasSubstr("empty"));
  std::filesystem::remove(path);
}

TEST(MeshIoRefuse, UnknownFormat) {
  ExpectRefused("hello, I am not a mesh\n", MeshFormat::kAuto, StatusCode::kParseError,
                "unknown format");
  ExpectRefused(std::string(100, '\x01'), MeshFormat::kAuto, StatusCode::kParseError,
                "unknown format");
  ExpectRefused("ply\nformat binary_middle_endian 1.0\nend_header\n", MeshFormat::kAuto,
                StatusCode::kUnsupported, "binary_middle_endian");
}

TEST(MeshIoRefuse, NoFaces) {
  ExpectRefused(
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float "
      "z\n"
      "end_header\n0 0 0\n",
      MeshFormat::kAuto, StatusCode::kParseError, "no faces");
  ExpectRefused(
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float "
      "z\n"
      "element face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n",
      MeshFormat::kAuto, StatusCode::kParseError, "no faces");
  ExpectRefused("v 0 0 0\nv 1 0 0\n", MeshFormat::kAuto, StatusCode::kParseError, "no faces");
  ExpectRefused(BinaryStl("binary", 0), MeshFormat::kAuto, StatusCode::kParseError, "no faces");
  ExpectRefused("solid empty\nendsolid empty\n", MeshFormat::kAuto, StatusCode::kParseError,
                "no faces");
}

TEST(MeshIoRefuse, IndexOutOfRangeNamesFaceIndexAndCount) {
  std::string ply =
      "ply\nformat ascii 1.0\nelement vertex 8502\nproperty float x\nproperty float y\nproperty "
      "float z\n"
      "element face 13\nproperty list uchar int vertex_indices\nend_header\n";
  for (int v = 0; v < 8502; ++v) ply += "0 0 " + std::to_string(v) + "\n";
  for (int f = 0; f < 12; ++f) ply += "3 0 1 2\n";
  ply += "3 1 9001 2\n";
  ExpectRefused(ply, MeshFormat::kAuto, StatusCode::kCorrupt,
                "ply: face 12 index 9001 >= vertex count 8502");
  ExpectRefused(kTriPlyHeader + "0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n", MeshFormat::kAuto,
                StatusCode::kCorrupt, "face 0 index -1 is not a vertex index");
  ExpectRefused(kTriPlyHeader + "0 0 0\n1 0 0\n0 1 0\n2 0 1\n", MeshFormat::kAuto,
                StatusCode::kParseError, "face 0 has 2 vertices");
  ExpectRefused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", MeshFormat::kAuto, StatusCode::kCorrupt,
                "line 4: vertex index 9 > vertex count 3");
  ExpectRefused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", MeshFormat::kAuto, StatusCode::kCorrupt,
                "index 0");
  ExpectRefused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 1 2\n", MeshFormat::kAuto, StatusCode::kCorrupt,
                "vertex index -4 reaches before the first vertex");
  ExpectRefused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//2 2 3\n", MeshFormat::kAuto, StatusCode::kCorrupt,
                "normal index 2 > normal count 0");
}

TEST(MeshIoRefuse, NonFiniteCoordinates) {
  ExpectRefused(kTriPlyHeader + "0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n", MeshFormat::kAuto,
                StatusCode::kCorrupt, "vertex 1 has a non-finite coordinate");
  ExpectRefused(kTriPlyHeader + "0 0 0\n1 0 0\n0 -inf 0\n3 0 1 2\n", MeshFormat::kAuto,
                StatusCode::kCorrupt, "vertex 2 has a non-finite coordinate");
  ExpectRefused(kTriPlyHeader + "0 0 0\n1 0 0\n0 1 -1e39\n3 0 1 2\n", MeshFormat::kAuto,
                StatusCode::kCorrupt,
                "vertex 2 has a non-finite coordinate");  // beyond the range of "property float"
  std::string bin = OddPlyBinary(false);
  const size_t body = bin.find("end_header\n") + 11;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::memcpy(&bin[body + 1], &nan, sizeof(nan));  // z of vertex 0
  ExpectRefused(bin, MeshFormat::kAuto, StatusCode::kCorrupt,
                "vertex 0 has a non-finite coordinate");
  ExpectRefused("v 0 0 0\nv 1 inf 0\nv 0 1 0\nf 1 2 3\n", MeshFormat::kAuto, StatusCode::kCorrupt,
                "line 2: non-finite 'v'");
  ExpectRefused(
      "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex nan 0 0\nvertex 0 1 "
      "0\nendloop\n"
      "endfacet\nendsolid x\n",
      MeshFormat::kAuto, StatusCode::kCorrupt, "line 5: non-finite vertex");
  std::string stl = BinaryStl("binary", 2);
  const float inf = std::numeric_limits<float>::infinity();
  std::memcpy(&stl[84 + 50 + 12 + 4], &inf, sizeof(inf));
  ExpectRefused(stl, MeshFormat::kAuto, StatusCode::kCorrupt, "triangle 1 has a non-finite vertex");
}

TEST(MeshIoRefuse, TruncatedBinary) {
  const std::string bin = OddPlyBinary(false);
  ExpectRefused(
      bin.substr(0, bin.size() - 10), MeshFormat::kAuto, StatusCode::kParseError,
      "ply: face 1 property 'vertex_index': list of 3 items does not fit in the remaining 9 bytes");
  const size_t body = bin.find("end_header\n") + 11;
  ExpectRefused(bin.substr(0, body + 30), MeshFormat::kAuto, StatusCode::kParseError,
                "ply: header claims 4 'vertex'");
  // Truncated past the guard: the cut is found while reading the items.
  ExpectRefused(bin.substr(0, body + 110), MeshFormat::kAuto, StatusCode::kParseError,
                "unexpected end of data");
  const std::string stl = BinaryStl("binary", 3);
  ExpectRefused(stl.substr(0, stl.size() - 1), MeshFormat::kStl, StatusCode::kParseError,
                "claims 3 triangles (234 bytes) but the data has 233 bytes (truncated)");
  ExpectRefused(stl.substr(0, 40), MeshFormat::kStl, StatusCode::kParseError,
                "shorter than the 84-byte header");
  // A count below the data (100 triangles fewer: their data was silently ignored).
  std::string low = BinaryStl("binary", 103);
  const uint32_t three = 3;
  std::memcpy(&low[80], &three, sizeof(three));
  ExpectRefused(low, MeshFormat::kStl, StatusCode::kParseError,
                "claims 3 triangles but the data holds 103");
  ExpectRefused("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1",
                MeshFormat::kAuto, StatusCode::kParseError, "expected a number, got end of data");
}

TEST(MeshIoRefuse, AbsurdCountsFailFast) {
  // A 1 kB binary PLY claiming 4e9 vertices.
  std::string ply =
      "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty "
      "float y\n"
      "property float z\nelement face 4000000000\nproperty list uchar int "
      "vertex_indices\nend_header\n";
  ply.resize(1024, '\0');
  // Each refusal names the header's claim: it comes from comparing the counts with the bytes left,
  // before anything is reserved (no timing here: speed is not a pass/fail test).
  ExpectRefused(ply, MeshFormat::kAuto, StatusCode::kParseError,
                "header claims 4000000000 'vertex' items");
  // The same in ascii, and a list claiming 4e9 items.
  std::string ascii = kTriPlyHeader;
  ascii.replace(ascii.find("vertex 3"), 8, "vertex 4000000000");
  ascii.resize(1024, ' ');
  ExpectRefused(ascii, MeshFormat::kAuto, StatusCode::kParseError,
                "header claims 4000000000 'vertex' items");
  ByteWriter w(false);
  w << 0.f << 0.f << 0.f << 1.f << 0.f << 0.f << 0.f << 1.f << 0.f << uint32_t{4000000000u}
    << int32_t{0};
  const std::string list_ply =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n" +
      w.bytes;
  ExpectRefused(list_ply, MeshFormat::kAuto, StatusCode::kParseError,
                "list of 4000000000 items does not fit");
  std::string stl = BinaryStl("binary", 2);
  const uint32_t huge = 0xffffffffu;
  std::memcpy(&stl[80], &huge, 4);
  ExpectRefused(stl, MeshFormat::kStl, StatusCode::kParseError, "claims 4294967295 triangles");
}

TEST(MeshIoRefuse, MalformedHeadersAndValues) {
  ExpectRefused("ply\nformat ascii 1.0\nelement vertex 3\n", MeshFormat::kAuto,
                StatusCode::kParseError, "no 'end_header'");
  ExpectRefused("ply\nformat ascii 1.0\nelement vertex 3\nproperty flaot x\nend_header\n",
                MeshFormat::kAuto, StatusCode::kParseError,
                "line 4: unknown property type 'flaot'");
  ExpectRefused("ply\nformat ascii 1.0\nelement vertex -3\nend_header\n", MeshFormat::kAuto,
                StatusCode::kParseError, "invalid count '-3'");
  ExpectRefused("ply\nformat ascii 1.0\nproperty float x\nend_header\n", MeshFormat::kAuto,
                StatusCode::kParseError, "'property' before any 'element'");
  ExpectRefused(
      "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int "
      "vertex_indices\nend_header\n3 0 1 2\n",
      MeshFormat::kAuto, StatusCode::kParseError, "no 'vertex' element");
  ExpectRefused(kTriPlyHeader + "0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n", MeshFormat::kAuto,
                StatusCode::kParseError, "ply: vertex 1 property 'y': 'zero' is not a float");
  ExpectRefused(kTriPlyHeader + "0 0 0\n1 0 0\n0 1 0\n300 0 1 2\n", MeshFormat::kAuto,
                StatusCode::kParseError, "300 is out of range for uchar");
  ExpectRefused(
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float "
      "z\n"
      "element face 1\nproperty list uchar int vertex_indices\nproperty int label\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 7\n",
      MeshFormat::kAuto, StatusCode::kCorrupt,
      "face 0 label 7 is not 0 (unknown), 1 (gingiva) or 2 (tooth)");
  ExpectRefused(
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0\n1 0\n0 1\n3 0 1 "
      "2\n",
      MeshFormat::kAuto, StatusCode::kParseError, "lacks x, y or z");
  ExpectRefused(
      "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\n",
      MeshFormat::kAuto, StatusCode::kParseError, "facet has 2 vertices");
  ExpectRefused("solid x\nfacet normal 0 0 1\ninner loop\n", MeshFormat::kAuto,
                StatusCode::kParseError, "line 3: expected 'outer', got 'inner'");
  ExpectRefused("v 0 0\nf 1 1 1\n", MeshFormat::kAuto, StatusCode::kParseError,
                "line 1: 'v' needs 3 numbers");
  ExpectRefused("v 0 0 0\nf 1 1\n", MeshFormat::kAuto, StatusCode::kParseError,
                "face has 2 corners");
  ExpectRefused("v 0 0 0\nf 1 a 1\n", MeshFormat::kAuto, StatusCode::kParseError,
                "vertex index 'a' is not an integer");
  // A forced parser on the wrong content says what it expected.
  ExpectRefused(OddPlyAscii(), MeshFormat::kStl, StatusCode::kParseError, "stl");
  ExpectRefused("v 0 0 0\n", MeshFormat::kPly, StatusCode::kParseError, "missing 'ply' magic");
}

TEST(MeshIoRefuse, FileErrors) {
  TriangleMesh m;
  const std::string missing = TempPath("does_not_exist.ply");
  Status s = LoadMesh(missing, &m);
  EXPECT_EQ(s.code(), StatusCode::kNotFound);
  EXPECT_THAT(s.message(), HasSubstr(missing));
  s = LoadMesh(std::filesystem::temp_directory_path().string(), &m);
  EXPECT_EQ(s.code(), StatusCode::kIoError);
  EXPECT_EQ(LoadMesh(missing, nullptr).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(LoadMeshFromMemory(OddPlyAscii(), MeshFormat::kAuto, nullptr).code(),
            StatusCode::kInvalidArgument);
  // The path is named in load errors.
  const std::string bad = TempPath("bad_index.ply");
  WriteFile(bad, kTriPlyHeader + "0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n");
  s = LoadMesh(bad, &m);
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  EXPECT_THAT(s.message(), HasSubstr(bad + ": ply: face 0 index 5 >= vertex count 3"));
  std::filesystem::remove(bad);
}

TEST(MeshIoSave, RefusesBadMeshesAndPaths) {
  EXPECT_EQ(SavePlyBinary(TempPath("x.ply"), TriangleMesh()).code(), StatusCode::kInvalidArgument);
  TriangleMesh bad = DecoratedCube();
  bad.faces[0][0] = 99;
  Status s = SavePlyAscii(TempPath("x.ply"), bad);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("face 0 index 99"));
  TriangleMesh nan = DecoratedCube();
  nan.vertices[2].x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(SaveStlBinary(TempPath("x.stl"), nan).code(), StatusCode::kInvalidArgument);
  TriangleMesh huge = DecoratedCube();
  huge.vertices[1].y() = 1e39;  // beyond float
  s = SavePlyBinary(TempPath("x.ply"), huge);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("vertex 1 is not a finite float"));
  s = SaveStlBinary("/nonexistent_dir_d3d/x.stl", DecoratedCube());
  EXPECT_EQ(s.code(), StatusCode::kIoError);
  EXPECT_THAT(s.message(), HasSubstr("/nonexistent_dir_d3d/x.stl"));
}

// ---------------------------------------------------------------------------------------------
// Labels from colours

TEST(MeshIoLabels, SaturationSplitsGingivaFromTeeth) {
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.face_colors = {{255, 255, 255, 255}, {150, 150, 150, 255}, {200, 180, 170, 255},
                   {255, 255, 0, 255},   {0, 255, 0, 255},     {255, 125, 0, 255},
                   {0, 0, 255, 255},     {255, 0, 255, 255},   {0, 255, 255, 255},
                   {100, 60, 60, 255}};
  m.faces.assign(m.face_colors.size(), Eigen::Vector3i(0, 1, 2));
  LabelFacesFromColors(&m);
  using L = SurfaceLabel;
  EXPECT_EQ(m.face_labels,
            (std::vector<L>{L::kGingiva, L::kGingiva, L::kGingiva, L::kTooth, L::kTooth, L::kTooth,
                            L::kTooth, L::kTooth, L::kTooth, L::kTooth}));
  EXPECT_EQ(m.face_tooth_ids, std::vector<uint8_t>(10, 0));
  EXPECT_NO_THROW(m.Check());

  TriangleMesh plain;
  plain.vertices = m.vertices;
  plain.faces = {{0, 1, 2}};
  LabelFacesFromColors(&plain);
  EXPECT_TRUE(plain.face_labels.empty());
  LabelFacesFromColors(nullptr);
}

// ---------------------------------------------------------------------------------------------
// The real intraoral scan of ../shared/data

TEST(MeshIoRealData, UpperArch) {
  const std::string path = std::string(D3D_SHARED_DATA_DIR) + "/dental/upper_arch_0189MCMV.ply";
  if (!std::filesystem::exists(path))
    GTEST_SKIP() << "../shared/data absent: " << path << " not found";
  TriangleMesh arch;
  const Status s = LoadMesh(path, &arch);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(arch.vertices.size(), 8502u);
  EXPECT_EQ(arch.faces.size(), 16000u);
  EXPECT_EQ(arch.vertex_normals.size(), 8502u);
  EXPECT_EQ(arch.face_colors.size(), 16000u);
  const auto [lo, hi] = arch.Bounds();
  const Eigen::Vector3d extent = hi - lo;
  EXPECT_NEAR(extent.x(), 62.3, 0.2);
  EXPECT_NEAR(extent.y(), 19.5, 0.2);
  EXPECT_NEAR(extent.z(), 50.7, 0.2);

  LabelFacesFromColors(&arch);
  const auto gingiva =
      std::count(arch.face_labels.begin(), arch.face_labels.end(), SurfaceLabel::kGingiva);
  const auto tooth =
      std::count(arch.face_labels.begin(), arch.face_labels.end(), SurfaceLabel::kTooth);
  EXPECT_EQ(gingiva, 8300);
  EXPECT_EQ(tooth, 7700);

  // Labels survive a binary PLY round trip.
  const std::string out = TempPath("arch.ply");
  ASSERT_TRUE(SavePlyBinary(out, arch).ok());
  TriangleMesh back;
  ASSERT_TRUE(LoadMesh(out, &back).ok());
  EXPECT_EQ(back.face_labels, arch.face_labels);
  EXPECT_EQ(back.faces, arch.faces);
  EXPECT_NEAR(back.SurfaceArea(), arch.SurfaceArea(), 1e-6 * arch.SurfaceArea());
  std::filesystem::remove(out);
}

// ---------------------------------------------------------------------------------------------
// Deterministic mutation test (the libFuzzer target's body on seeded random mutations)

std::vector<std::string> MutationSeeds() {
  TriangleMesh small = DecoratedCube();
  const std::string ply_path = TempPath("seed.ply");
  const std::string stl_path = TempPath("seed.stl");
  EXPECT_TRUE(SavePlyBinary(ply_path, small).ok());
  EXPECT_TRUE(SaveStlBinary(stl_path, small).ok());
  auto slurp = [](const std::string& p) {
    std::ifstream f(p, std::ios::binary);
    std::ostringstream ss;
    ss << f.rdbuf();
    return ss.str();
  };
  std::vector<std::string> seeds = {OddPlyAscii(),
                                    OddPlyBinary(false),
                                    OddPlyBinary(true),
                                    slurp(ply_path),
                                    slurp(stl_path),
                                    "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex "
                                    "1 0 0\nvertex 1 1 0\nendloop\nendfacet\n"
                                    "facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 1 "
                                    "0\nvertex 0 1 0\nendloop\nendfacet\nendsolid s\n",
                                    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1 2 "
                                    "3\nf 1/1 3/1 4/1\nf -4//1 -3//1 -2//1\n"
                                    "f 1/1/1 2/1/1 3/1/1 4/1/1\n"};
  std::filesystem::remove(ply_path);
  std::filesystem::remove(stl_path);
  return seeds;
}

void Mutate(std::string* s, std::mt19937* rng) {
  auto pick = [rng](size_t n) { return n == 0 ? size_t{0} : static_cast<size_t>((*rng)() % n); };
  static constexpr std::array<char, 8> kInteresting = {'0', '9', '-', ' ', '\n', '\0', '\xff', '/'};
  switch ((*rng)() % 6) {
    case 0:  // bit flip
      if (!s->empty()) (*s)[pick(s->size())] ^= static_cast<char>(1 << ((*rng)() % 8));
      break;
    case 1:  // truncation
      s->resize(pick(s->size() + 1));
      break;
    case 2: {  // inserted garbage
      std::string garbage(1 + pick(16), '\0');
      for (char& c : garbage) c = static_cast<char>((*rng)() & 0xff);
      s->insert(pick(s->size() + 1), garbage);
      break;
    }
    case 3:  // an interesting byte
      if (!s->empty()) (*s)[pick(s->size())] = kInteresting[pick(kInteresting.size())];
      break;
    case 4:  // a huge 32-bit value (counts, indices)
      if (s->size() >= 4) {
        const uint32_t v = ((*rng)() % 2) ? 0xffffffffu : 0x7fffffffu;
        std::memcpy(s->data() + pick(s->size() - 3), &v, 4);
      }
      break;
    default: {  // a duplicated chunk
      if (s->empty()) break;
      const size_t from = pick(s->size());
      const size_t len = 1 + pick(std::min<size_t>(64, s->size() - from));
      s->insert(pick(s->size() + 1), s->substr(from, len));
      break;
    }
  }
}

TEST(MeshIoFuzz, SeededMutationsNeverBreakTheContract) {
  const std::vector<std::string> seeds = MutationSeeds();
  for (const std::string& seed : seeds) {
    const FuzzLoadOutcome o =
        FuzzLoadMeshOnce(reinterpret_cast<const uint8_t*>(seed.data()), seed.size());
    ASSERT_TRUE(o.violation.empty()) << o.violation;
    ASSERT_GE(o.loaded, 2) << "seed does not load: " << seed.substr(0, 40);
  }
  std::mt19937 rng(20240521u);
  int loaded = 0;
  int refused = 0;
  for (int i = 0; i < 2000; ++i) {
    std::string s = seeds[static_cast<size_t>(i) % seeds.size()];
    const int mutations = 1 + static_cast<int>(rng() % 4);
    for (int k = 0; k < mutations; ++k) Mutate(&s, &rng);
    const FuzzLoadOutcome o =
        FuzzLoadMeshOnce(reinterpret_cast<const uint8_t*>(s.data()), s.size());
    ASSERT_TRUE(o.violation.empty()) << "mutation " << i << ": " << o.violation;
    loaded += o.loaded;
    refused += o.refused;
  }
  RecordProperty("loads_ok", loaded);
  RecordProperty("loads_refused", refused);
  // Both outcomes happen: the mutations exercise the parsers, not only their first check.
  EXPECT_GT(loaded, 200);
  EXPECT_GT(refused, 2000);
}

}  // namespace
}  // namespace d3d
