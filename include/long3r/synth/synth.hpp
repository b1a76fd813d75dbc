// Procedural indoor scenes with exact ground truth, for testing, evaluation
// and training without real datasets.
//
// A scene is a closed box room (walls, floor, ceiling) with furniture-like
// boxes, vertical cylinders and spheres, and wall pictures/rugs (thin boxes).
// Every surface has a procedural texture (multi-octave value noise plus a
// pattern: tiles, bricks, checks, stripes, dots, wood or marble bands, with
// per-cell colour variation) so that images carry features at several scales.
// Shading is Lambertian (one directional and one point light) plus ambient,
// without shadows, so a surface point has the same colour from every view.
//
// Frames: world W has z up, the room spans [0, size.x] x [0, size.y] x
// [0, size.z] metres. Camera poses are T_W_C of the camera optical frame
// C (x right, y down, z forward). Depth is metric z-depth along the optical
// axis. Rendering casts one ray per pixel centre (optionally n x n
// sub-pixel rays averaged for colour; depth always from the centre ray).
//
// Everything is a deterministic function of the seed: the random numbers come
// from std::mt19937_64 (whose output the standard fixes) through the
// distributions implemented here, so results do not depend on the standard
// library's distribution code. Images are identical for any thread count.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "long3r/pipeline/pinhole_intrinsics.hpp"

namespace long3r::synth {

// Seeded random numbers with portable distributions.
class Rng {
 public:
  explicit Rng(uint64_t seed) : engine_(seed) {}
  uint64_t next_u64() { return engine_(); }
  double uniform();                                       // [0, 1), 53 random bits
  double uniform(double lo, double hi);                   // [lo, hi)
  int uniform_int(int lo, int hi);                        // [lo, hi], inclusive
  double normal(double mean = 0.0, double stddev = 1.0);  // Box-Muller
  bool bernoulli(double p) { return uniform() < p; }

 private:
  std::mt19937_64 engine_;
};

enum class Pattern { kNoise, kTiles, kBricks, kChecker, kStripes, kDots, kWood, kMarble };

// Surface appearance. Colours are linear RGB in [0, 1].
struct Material {
  Eigen::Vector3f base{0.5f, 0.5f, 0.5f};
  Eigen::Vector3f accent{0.2f, 0.2f, 0.2f};
  Pattern pattern = Pattern::kNoise;
  float pattern_scale = 0.3f;   // metres: tile / brick / stripe period
  float pattern_angle = 0.0f;   // radians, rotation of the pattern in the surface
  float noise_scale = 0.5f;     // metres: wavelength of the coarsest noise octave
  float noise_amount = 0.3f;    // noise contrast
  float cell_variation = 0.2f;  // per-tile/brick/dot colour variation
  uint32_t seed = 0;
};

enum class ShapeType { kBox, kCylinder, kSphere };

// Furniture. Boxes may be rotated about the world z axis (yaw); cylinders
// are vertical.
struct Shape {
  ShapeType type = ShapeType::kBox;
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  Eigen::Vector3d half_size =
      Eigen::Vector3d::Constant(0.5);  // box; cyl (r, r, h/2); sphere (r, r, r)
  double yaw = 0.0;
  int material = 0;
  std::string label;  // "table", "cabinet", "picture", ... (informational)

  // Euclidean distance from p to the solid (0 inside).
  double distance(const Eigen::Vector3d& p) const;
};

struct Scene {
  Eigen::Vector3d room_size{5.0, 4.0, 2.7};
  // Room surfaces: 0 x=0 wall, 1 x=max wall, 2 y=0 wall, 3 y=max wall, 4 floor, 5 ceiling.
  int room_material[6] = {0, 0, 0, 0, 0, 0};
  std::vector<Shape> shapes;
  std::vector<Material> materials;
  Eigen::Vector3d light_direction{0.3, 0.2, 1.0};  // towards the light (normalised on use)
  Eigen::Vector3d point_light{2.5, 2.0, 2.4};
  double ambient = 0.3, directional = 0.4, point_intensity = 0.45;
};

// Ray-scene intersection. `dir` need not be normalised; t is in units of it
// (so with dir = R * (x, y, 1) t is the z-depth). surface_id: room surface
// 0..5, or 16 * (shape index + 1) + face.
struct Hit {
  double t = 0.0;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();  // unit, facing the ray origin
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();      // surface coordinates in metres
  Eigen::Vector3d local = Eigen::Vector3d::Zero();   // point in the surface's own frame
  int material = 0;
  int surface_id = -1;
};
bool intersect(const Scene& scene, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
               Hit* hit);

// Texture colour (linear RGB) at a hit; footprint = metres per pixel there,
// used to fade out detail finer than a pixel.
Eigen::Vector3f shade(const Scene& scene, const Hit& hit, double footprint);

enum class TrajectoryType { kWalk, kOrbit, kPanReturn };
TrajectoryType trajectory_type_from_string(const std::string& name);  // walk|orbit|pan
const char* to_string(TrajectoryType type);

struct SceneConfig {
  double min_width = 4.0, max_width = 7.0;    // room x, y extent range (m)
  double min_height = 2.5, max_height = 3.2;  // room z
  int min_objects = 10, max_objects = 18;     // furniture (boxes, cylinders, spheres)
  int pictures = 4;                           // flat textured boxes on the walls
};

struct TrajectoryConfig {
  TrajectoryType type = TrajectoryType::kWalk;
  int frames = 300;
  double speed = 0.02;                        // metres per frame (peak speed for pan)
  double max_yaw_rate_deg = 1.5;              // degrees per frame bound on turning (pan, walk)
  double clearance = 0.5;                     // min distance of the camera from any surface (m)
  double min_height = 1.1, max_height = 1.7;  // camera height range (m)
  double pitch_deg = -12.0;                   // mean look-down angle
  double roll_deg = 2.0;                      // amplitude of a slow roll wobble
};

struct RenderOptions {
  int threads = 2;      // rows are split among this many std::threads
  int supersample = 1;  // n: n x n colour rays per pixel
};

struct SequenceConfig {
  uint64_t seed = 1;
  SceneConfig scene;
  TrajectoryConfig trajectory;
  PinholeIntrinsics intrinsics = PinholeIntrinsics::from_hfov(224, 224, 70.0);
  double fps = 30.0;
  double start_time = 0.0;  // timestamp of frame 0 (s)
};

// Scene, poses and timestamps (no images yet).
struct Sequence {
  SequenceConfig config;
  Scene scene;
  std::vector<double> stamps;
  std::vector<Eigen::Isometry3d> poses;  // T_W_C
};

// Builds the room, the camera path (kept `clearance` away from the walls),
// then places furniture kept `clearance` away from every camera position.
// Throws std::invalid_argument for bad configs (e.g. frames < 1, a room too
// small for the clearance).
Sequence generate_sequence(const SequenceConfig& config);

struct RenderedFrame {
  cv::Mat bgr;         // CV_8UC3, OpenCV BGR order, sRGB-encoded
  cv::Mat depth;       // CV_32FC1, z-depth in metres (0 where no surface)
  cv::Mat surface_id;  // CV_32SC1, Hit::surface_id (-1 where no surface)
};
RenderedFrame render_frame(const Scene& scene, const Eigen::Isometry3d& T_W_C,
                           const PinholeIntrinsics& intrinsics, const RenderOptions& options = {});

struct WriteStats {
  int frames = 0;
  double render_seconds = 0.0;  // wall time spent rendering
  double write_seconds = 0.0;   // wall time spent encoding and writing files
};

// Writes the TUM layout (see tum_dataset.hpp) into `dir` (created):
// rgb/<t>.png, depth/<t>.png (uint16, metres * 5000, 0 beyond 13.1 m),
// rgb.txt, depth.txt, groundtruth.txt, calibration.txt, plus scene.json
// (config and scene description). <t> is the timestamp with 6 decimals.
// `progress(i, n)` is called after each frame when given.
WriteStats write_tum_sequence(const Sequence& sequence, const std::string& dir,
                              const RenderOptions& options = {},
                              const std::function<void(int, int)>& progress = {});

// Depth PNG scale shared with the TUM reader's default.
constexpr double kTumDepthFactor = 5000.0;

}  // namespace long3r::synth
