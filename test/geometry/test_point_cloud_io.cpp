// save_point_cloud / load_point_cloud: every format round-trips exactly, the
// bytes written are the documented layout, and the PLY reader takes the
// variants other tools write (ascii, big endian, double, extra elements);
// PCL's readers take what it writes.
#include <gtest/gtest.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "long3r/geometry/cv/pcl_cloud.hpp"
#include "long3r/geometry/cv/point_cloud_io.hpp"

namespace long3r {
namespace {

namespace fs = std::filesystem;

std::string temp_dir(const std::string& name) {
  const auto d = fs::path(LONG3R_BINARY_DIR) / "test_tmp" / name;
  fs::remove_all(d);
  fs::create_directories(d);
  return d.string();
}

std::string read_all(const std::string& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::vector<Eigen::Vector3f> random_points(int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-3.0f, 3.0f);
  std::vector<Eigen::Vector3f> p(static_cast<size_t>(n));
  for (auto& x : p) x = Eigen::Vector3f(u(rng), u(rng), u(rng));
  return p;
}

TEST(PointCloudIo, EveryFormatRoundTripsExactly) {
  const std::string dir = temp_dir("point_cloud_io_roundtrip");
  const auto pts = random_points(500, 1);
  std::vector<Rgb8> colors(pts.size());
  for (size_t i = 0; i < colors.size(); ++i) {
    colors[i] = {static_cast<uint8_t>(i), static_cast<uint8_t>(3 * i), static_cast<uint8_t>(7 * i)};
  }
  int files = 0;
  for (const char* ext : {".ply", ".pcd", ".xyz", ".txt", ".PLY"}) {
    for (bool ascii : {false, true}) {
      for (bool with_colors : {false, true}) {
        const std::string path = dir + "/c" + std::to_string(files++) + ext;
        PointCloudWriteOptions o;
        o.ascii = ascii;
        save_point_cloud(path, pts, with_colors ? &colors : nullptr, o);
        EXPECT_EQ(load_point_cloud(path), pts) << path;
      }
    }
  }
  EXPECT_EQ(static_cast<int>(std::distance(fs::directory_iterator(dir), {})), files);
  EXPECT_EQ(load_point_cloud(dir + "/c0.ply").size(), pts.size());
}

// What users open our files with: PCL's own readers take ~save_map's and
// long3r_reconstruct's coloured PLY and PCD, binary and ascii, point for point.
TEST(PointCloudIo, PclReadsThemBackAsColouredClouds) {
  const std::string dir = temp_dir("point_cloud_io_pcl");
  const auto pts = random_points(300, 3);
  std::vector<Rgb8> colors(pts.size());
  for (size_t i = 0; i < colors.size(); ++i) {
    colors[i] = {static_cast<uint8_t>(5 * i), static_cast<uint8_t>(i),
                 static_cast<uint8_t>(255 - i)};
  }
  const ColoredCloud expected = to_pcl_cloud(pts, colors);
  for (const char* ext : {".ply", ".pcd"}) {
    for (bool ascii : {false, true}) {
      const std::string path = dir + "/map" + (ascii ? "_ascii" : "") + ext;
      PointCloudWriteOptions o;
      o.ascii = ascii;
      o.comment = "long3r test";
      save_point_cloud(path, pts, &colors, o);
      ColoredCloud read;
      const int rc = std::string(ext) == ".ply" ? pcl::io::loadPLYFile(path, read)
                                                : pcl::io::loadPCDFile(path, read);
      ASSERT_EQ(rc, 0) << path;
      ASSERT_EQ(read.size(), expected.size()) << path;
      for (size_t i = 0; i < read.size(); ++i) {
        ASSERT_EQ(read[i].getVector3fMap(), expected[i].getVector3fMap()) << path << " " << i;
        ASSERT_EQ(read[i].r, expected[i].r) << path << " " << i;
        ASSERT_EQ(read[i].g, expected[i].g) << path << " " << i;
        ASSERT_EQ(read[i].b, expected[i].b) << path << " " << i;
      }
    }
  }
  std::vector<Rgb8> fewer(colors.begin(), colors.end() - 1);
  EXPECT_THROW(to_pcl_cloud(pts, fewer), std::invalid_argument);
}

// The layouts long3r_eval's outputs and the tests rely on, byte for byte.
TEST(PointCloudIo, WrittenBytesAreTheDocumentedLayout) {
  const std::string dir = temp_dir("point_cloud_io_bytes");
  const std::vector<Eigen::Vector3f> pts = {{1.0f, -2.5f, 0.125f}, {0.1f, 0.2f, 0.3f}};
  const std::vector<Rgb8> colors = {Rgb8{1, 2, 3}, Rgb8{250, 128, 0}};

  save_point_cloud(dir + "/a.ply", pts);
  std::string raw(reinterpret_cast<const char*>(pts.data()), 2 * 3 * sizeof(float));
  EXPECT_EQ(read_all(dir + "/a.ply"),
            "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
            "property float y\nproperty float z\nend_header\n" +
                raw);

  PointCloudWriteOptions o;
  o.comment = "long3r map";
  save_point_cloud(dir + "/b.ply", pts, &colors, o);
  std::string rec;
  for (int i = 0; i < 2; ++i) {
    rec.append(reinterpret_cast<const char*>(pts[static_cast<size_t>(i)].data()), 12);
    rec.append(reinterpret_cast<const char*>(colors[static_cast<size_t>(i)].data()), 3);
  }
  EXPECT_EQ(read_all(dir + "/b.ply"),
            "ply\nformat binary_little_endian 1.0\ncomment long3r map\nelement vertex 2\n"
            "property float x\nproperty float y\nproperty float z\nproperty uchar red\n"
            "property uchar green\nproperty uchar blue\nend_header\n" +
                rec);

  o.ascii = true;
  save_point_cloud(dir + "/c.pcd", pts, &colors, o);
  EXPECT_EQ(read_all(dir + "/c.pcd"),
            "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\n"
            "SIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\n"
            "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n"
            "1 -2.5 0.125 66051\n0.100000001 0.200000003 0.300000012 16416768\n");
  save_point_cloud(dir + "/d.xyz", pts, &colors);
  EXPECT_EQ(read_all(dir + "/d.xyz"),
            "1 -2.5 0.125 1 2 3\n0.100000001 0.200000003 0.300000012 250 128 0\n");
}

TEST(PointCloudIo, PlyReaderTakesOtherWritersVariants) {
  const std::string dir = temp_dir("point_cloud_io_ply");
  {
    std::ofstream ascii(dir + "/b.ply");
    ascii << "ply\nformat ascii 1.0\ncomment test\nelement vertex 2\nproperty double x\n"
             "property uchar red\nproperty double y\nproperty double z\n"
             "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
             "1.5 255 2.5 -3\n4 0 5 6\n3 0 1 1\n";
  }
  const auto b = load_point_cloud(dir + "/b.ply");
  ASSERT_EQ(b.size(), 2u);
  EXPECT_EQ(b[0], Eigen::Vector3f(1.5f, 2.5f, -3.0f));
  EXPECT_EQ(b[1], Eigen::Vector3f(4.0f, 5.0f, 6.0f));

  // Big endian, double coordinates after a list element (skipped), CRLF header.
  {
    std::ofstream big(dir + "/be.ply", std::ios::binary);
    big << "ply\r\nformat binary_big_endian 1.0\r\nelement camera 1\r\n"
           "property list uchar short k\r\nelement vertex 1\r\nproperty short id\r\n"
           "property double x\r\nproperty double y\r\nproperty double z\r\nend_header\n";
    const unsigned char camera[] = {2, 0, 1, 0, 2};
    big.write(reinterpret_cast<const char*>(camera), sizeof(camera));
    const unsigned char id[] = {0x01, 0x02};
    big.write(reinterpret_cast<const char*>(id), 2);
    for (double v : {0.25, -8.0, 1e3}) {
      unsigned char le[8], be[8];
      std::memcpy(le, &v, 8);
      for (int i = 0; i < 8; ++i) be[i] = le[7 - i];
      big.write(reinterpret_cast<const char*>(be), 8);
    }
  }
  // The camera element comes first and is skipped; the vertex is read.
  const auto be = load_point_cloud(dir + "/be.ply");
  ASSERT_EQ(be.size(), 1u);
  EXPECT_EQ(be[0], Eigen::Vector3f(0.25f, -8.0f, 1000.0f));

  {
    std::ofstream xyz(dir + "/c.xyz");
    xyz << "# x y z\n1 2 3\n\n4,5,6,0.5\n";
  }
  const auto c = load_point_cloud(dir + "/c.xyz");
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c[1], Eigen::Vector3f(4.0f, 5.0f, 6.0f));
}

TEST(PointCloudIo, PcdDropsNonFinitePoints) {
  const std::string dir = temp_dir("point_cloud_io_pcd");
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<Eigen::Vector3f> pts = {{1, 2, 3}, {nan, 0, 0}, {4, 5, 6}};
  save_point_cloud(dir + "/n.pcd", pts);
  EXPECT_EQ(load_point_cloud(dir + "/n.pcd"), (std::vector<Eigen::Vector3f>{{1, 2, 3}, {4, 5, 6}}));
}

TEST(PointCloudIo, Errors) {
  const std::string dir = temp_dir("point_cloud_io_errors");
  const auto pts = random_points(3, 2);
  EXPECT_THROW(load_point_cloud(dir + "/missing.ply"), std::runtime_error);
  EXPECT_THROW(load_point_cloud(dir + "/missing.pcd"), std::runtime_error);
  EXPECT_THROW(load_point_cloud(dir + "/c.unknown"), std::runtime_error);
  { std::ofstream(dir + "/bad.xyz") << "1 2\n"; }
  EXPECT_THROW(load_point_cloud(dir + "/bad.xyz"), std::runtime_error);
  {
    std::ofstream(dir + "/bad.ply") << "ply\nformat ascii 1.0\nelement vertex 2\n"
                                       "property float x\nproperty float y\nend_header\n1 2\n";
  }
  EXPECT_THROW(load_point_cloud(dir + "/bad.ply"), std::runtime_error);
  try {
    save_point_cloud(dir + "/a.obj", pts);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'.obj'"), std::string::npos) << e.what();
  }
  const std::vector<Rgb8> two(2);
  EXPECT_THROW(save_point_cloud(dir + "/a.ply", pts, &two), std::invalid_argument);
  EXPECT_THROW(save_point_cloud(dir + "/no/such/dir/a.ply", pts), std::runtime_error);
  // Only the two hand-made bad files: nothing written, no temporaries left.
  EXPECT_EQ(static_cast<int>(std::distance(fs::directory_iterator(dir), {})), 2);
}

// A mesh's PLY: PCL reads it back as a polygon mesh with the same vertices,
// colours and triangles (binary and ascii), and our reader takes its vertices.
TEST(PointCloudIo, MeshPlyIsReadByPcl) {
  const std::string dir = temp_dir("point_cloud_io_mesh");
  const std::vector<Eigen::Vector3f> vertices{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0.5f}};
  const std::vector<Rgb8> colors{{255, 0, 0}, {0, 255, 0}, {0, 0, 255}, {10, 20, 30}};
  const std::vector<Triangle> triangles{{0, 1, 2}, {1, 3, 2}};
  for (const bool ascii : {false, true}) {
    SCOPED_TRACE(ascii ? "ascii" : "binary");
    PointCloudWriteOptions options;
    options.ascii = ascii;
    const std::string path = dir + (ascii ? "/a.ply" : "/b.ply");
    save_mesh_ply(path, vertices, &colors, triangles, options);
    EXPECT_EQ(load_point_cloud(path), vertices);
    pcl::PolygonMesh mesh;
    ASSERT_EQ(pcl::io::loadPLYFile(path, mesh), 0);
    ASSERT_EQ(mesh.polygons.size(), triangles.size());
    for (std::size_t i = 0; i < triangles.size(); ++i) {
      ASSERT_EQ(mesh.polygons[i].vertices.size(), 3u);
      for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(mesh.polygons[i].vertices[a], static_cast<std::uint32_t>(triangles[i][a]));
      }
    }
    pcl::PointCloud<pcl::PointXYZRGB> cloud;
    pcl::fromPCLPointCloud2(mesh.cloud, cloud);
    ASSERT_EQ(cloud.size(), vertices.size());
    for (std::size_t i = 0; i < vertices.size(); ++i) {
      EXPECT_EQ(cloud[i].getVector3fMap(), vertices[i]);
      EXPECT_EQ(cloud[i].r, colors[i][0]);
      EXPECT_EQ(cloud[i].g, colors[i][1]);
      EXPECT_EQ(cloud[i].b, colors[i][2]);
    }
  }
  // A triangle naming a vertex that is not there, colours of another
  // length, another extension: refused, nothing written.
  EXPECT_THROW(save_mesh_ply(dir + "/c.ply", vertices, &colors, {{0, 1, 4}}),
               std::invalid_argument);
  EXPECT_THROW(save_mesh_ply(dir + "/c.ply", vertices, &colors, {{0, -1, 2}}),
               std::invalid_argument);
  const std::vector<Rgb8> two(2);
  EXPECT_THROW(save_mesh_ply(dir + "/c.ply", vertices, &two, triangles), std::invalid_argument);
  EXPECT_THROW(save_mesh_ply(dir + "/c.pcd", vertices, &colors, triangles), std::invalid_argument);
  EXPECT_FALSE(fs::exists(dir + "/c.ply"));
}

}  // namespace
}  // namespace long3r
