// Procedural indoor scenes with exact ground truth, for testing, evaluation
// and training without real datasets: a sequence's configuration, the
// generator's random numbers, and the scene with its camera path
// (synth/generate.cpp; rendering in render.hpp).
//
// Frames: world W has z up (geometry.hpp). Camera poses are T_W_C of the
// camera optical frame C (x right, y down, z forward).
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
// library's distribution code.
//
// The generator's core (library long3r_synth: Eigen and libtorch only, so
// that training data can be rendered on a machine without OpenCV). What needs
// OpenCV is in long3r_synth_cv: the LensRays constructor (cv/lens_rays.cpp),
// sensor noise and OpenCV images (cv/sensor_image.hpp) and the TUM writer
// (cv/tum_writer.hpp).
#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"
#include "long3r/synth/geometry.hpp"
#include "long3r/synth/render.hpp"

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

// Per-frame exposure gains for `stamps` (seconds); all 1 without exposure effects.
std::vector<double> exposure_gains(const SensorConfig& sensor, uint64_t seed,
                                   const std::vector<double>& stamps);

}  // namespace long3r::synth
