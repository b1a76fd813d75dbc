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
// A camera with lens distortion casts, for each pixel, the ray that the
// distortion model maps onto that pixel (LensRays), so images and depth are
// what the real distorted camera records.
//
// The `robot` path is a wheeled base on the floor with the camera rigidly
// mounted on it: T_W_C = T_W_B * T_B_C exactly, base_link B (REP-103: x
// forward, y left, z up) at z = 0 with yaw only.
//
// Sensor effects (exposure gain, mono output, noise) are applied per frame to
// the rendered image; all of them default to off.
//
// Everything is a deterministic function of the seed: the random numbers come
// from std::mt19937_64 (whose output the standard fixes) through the
// distributions implemented here, so results do not depend on the standard
// library's distribution code. Images are identical for any thread count.
//
// This header is the generator's core (library long3r_synth: Eigen and
// libtorch only, so that training data can be rendered on a machine without
// OpenCV). What needs OpenCV is in long3r_synth_cv: the LensRays constructor
// (cv/lens_rays.cpp), sensor noise and OpenCV images (cv/sensor_image.hpp) and the
// TUM writer (cv/tum_writer.hpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <Eigen/Geometry>

#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"

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

enum class TrajectoryType { kWalk, kOrbit, kPanReturn, kRobot };
TrajectoryType trajectory_type_from_string(const std::string& name);  // walk|orbit|pan|robot
const char* to_string(TrajectoryType type);

// Independent seeds for the parts of a sequence drawn after the scene (so
// enabling them leaves the scene and path as they were): splitmix64 of both.
uint64_t derived_seed(uint64_t seed, uint64_t stream);

// The camera on a wheeled base (trajectory `robot`): camera_link at (x, y, z)
// in base_link, pitched down by pitch_deg, no roll or yaw.
struct CameraMount {
  double x = 0.2, y = 0.0, z = 1.3;  // metres; base_link is on the floor
  double pitch_deg = 12.0;           // downwards (REP-103 pitch about +y)
  // T_base_link_camera_link (camera_link: x forward, y left, z up).
  Eigen::Isometry3d base_to_camera_link() const;
  // T_base_link_optical: base_to_camera_link() * camera_link_to_optical().
  Eigen::Isometry3d base_to_optical() const;
};
// The fixed rotation from a camera's body frame to its optical frame (x right,
// y down, z forward): rpy (-pi/2, 0, -pi/2), as camera drivers publish it.
Eigen::Isometry3d camera_link_to_optical();

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
  CameraMount mount;                          // robot only (its height replaces the range)
};

// Lens distortion of the rendered camera: OpenCV's / ROS's plumb_bob.
struct LensDistortion {
  double k1 = 0.0, k2 = 0.0, p1 = 0.0, p2 = 0.0, k3 = 0.0;
  bool any() const { return k1 != 0.0 || k2 != 0.0 || p1 != 0.0 || p2 != 0.0 || k3 != 0.0; }
  std::vector<double> coefficients() const { return {k1, k2, p1, p2, k3}; }  // OpenCV's order
};

// What the image sensor adds to the rendered radiance. Defaults: none.
struct SensorConfig {
  // Noise in 8-bit levels on the written values v: Gaussian with variance
  // read_noise^2 + shot_noise * v (read noise plus signal-dependent shot
  // noise), per pixel and channel, seeded by (seed, frame).
  double read_noise = 0.0;
  double shot_noise = 0.0;
  // Exposure gain on the linear radiance (before gamma; bright areas clip):
  // gain(t) = (1 + exposure_drift * w(t)) * step, w a slow random wave in
  // [-1, 1] (periods 6-12 s and 2.5-5 s); with probability exposure_step_prob
  // per frame the step factor is redrawn log-uniformly in
  // [1 / (1 + exposure_step), 1 + exposure_step].
  double exposure_drift = 0.0;
  double exposure_step_prob = 0.0;
  double exposure_step = 0.0;
  bool mono = false;  // grey images (8-bit luma of the colour render)

  bool noise() const { return read_noise > 0.0 || shot_noise > 0.0; }
  bool exposure() const { return exposure_drift > 0.0 || exposure_step_prob > 0.0; }
  bool any() const { return noise() || exposure() || mono; }
};

struct RenderOptions {
  int threads = 2;      // rows are split among this many std::threads
  int supersample = 1;  // n: n x n colour rays per pixel
  float gain = 1.0f;    // exposure: scales the linear radiance before encoding
};

struct SequenceConfig {
  uint64_t seed = 1;
  SceneConfig scene;
  TrajectoryConfig trajectory;
  PinholeIntrinsics intrinsics = PinholeIntrinsics::from_hfov(224, 224, 70.0);
  LensDistortion distortion;  // of the image described by `intrinsics`
  SensorConfig sensor;
  double fps = 30.0;
  double start_time = 0.0;  // timestamp of frame 0 (s)
};

// Scene, poses and timestamps (no images yet).
struct Sequence {
  SequenceConfig config;
  Scene scene;
  std::vector<double> stamps;
  std::vector<Eigen::Isometry3d> poses;       // T_W_C
  std::vector<Eigen::Isometry3d> base_poses;  // T_W_B, robot only (poses = T_W_B * mount)
  std::vector<double> exposure;               // per-frame gain (all 1 without exposure effects)
};

// Builds the room, the camera path (kept `clearance` away from the walls),
// then places furniture kept `clearance` away from every camera position.
// Throws std::invalid_argument for bad configs (e.g. frames < 1, a room too
// small for the clearance).
Sequence generate_sequence(const SequenceConfig& config);

// CPU tensors, row-major (the memory layout of the OpenCV images of the same
// content: cv/sensor_image.hpp makes those).
struct RenderedFrame {
  at::Tensor bgr;         // [H, W, 3] uint8, BGR order, sRGB-encoded
  at::Tensor depth;       // [H, W] float32, z-depth in metres (0 where no surface)
  at::Tensor surface_id;  // [H, W] int32, Hit::surface_id (-1 where no surface)
};
RenderedFrame render_frame(const Scene& scene, const Eigen::Isometry3d& T_W_C,
                           const PinholeIntrinsics& intrinsics, const RenderOptions& options = {});

// The rays of a camera with lens distortion: for every pixel centre (and the
// n x n sub-pixel samples of supersampling) the normalised ray (x, y, 1) that
// the plumb_bob model maps onto it, found with cv::undistortPoints (iterated
// to convergence and checked by projecting back), once per camera. The
// constructor is OpenCV's side (long3r_synth_cv); rendering with the table
// is not.
class LensRays {
 public:
  // Throws std::invalid_argument when the model cannot be inverted over the
  // image (a back-projected ray misses its pixel by more than 1e-6 px).
  LensRays(const PinholeIntrinsics& intrinsics, const LensDistortion& distortion,
           int supersample = 1);
  const PinholeIntrinsics& intrinsics() const { return k_; }
  int supersample() const { return n_; }
  // Normalised ray through pixel (u, v); sample s in [0, n*n) of its n x n grid.
  const Eigen::Vector2d& centre(int u, int v) const { return centre_[index(u, v)]; }
  const Eigen::Vector2d& sample(int u, int v, int s) const {
    return samples_[index(u, v) * n_ * n_ + s];
  }
  // Size of the pixel in normalised coordinates (sqrt of the Jacobian's
  // determinant; 1/f for a pinhole), for the texture filter footprint.
  double pixel_size(int u, int v) const { return pixel_size_[index(u, v)]; }

 private:
  size_t index(int u, int v) const { return static_cast<size_t>(v) * k_.width + u; }
  PinholeIntrinsics k_;
  int n_ = 1;
  std::vector<Eigen::Vector2d> centre_, samples_;
  std::vector<double> pixel_size_;
};
// Renders through a distorted lens: pixel (u, v) shows, and its depth is the
// z-depth of, what lies along rays.centre(u, v). options.supersample must
// equal rays.supersample().
RenderedFrame render_frame(const Scene& scene, const Eigen::Isometry3d& T_W_C, const LensRays& rays,
                           const RenderOptions& options = {});

// Per-frame exposure gains for `stamps` (seconds); all 1 without exposure effects.
std::vector<double> exposure_gains(const SensorConfig& sensor, uint64_t seed,
                                   const std::vector<double>& stamps);

}  // namespace long3r::synth
