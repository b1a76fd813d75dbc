// long3r_synth: renders a procedural indoor sequence with exact ground truth
// into a TUM RGB-D style folder (see include/long3r/synth/generate.hpp, docs/evaluation.md).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <string>

#include "long3r/config/cli_options.hpp"
#include "long3r/synth/cv/tum_writer.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"

int main(int argc, char** argv) {
  using namespace long3r::synth;
  SequenceConfig cfg;
  RenderOptions ropt;
  std::string out;
  int width = 224, height = 224;
  double hfov = 70.0, fx = 0, fy = 0, cx = -1, cy = -1;
  bool quiet = false;
  int image_every = 1;
  long3r::CliOptions cli("long3r_synth");
  cli.option("--out", "DIR", &out, "the TUM RGB-D style folder to write").required();
  cli.option("--seed", "N", &cfg.seed, "scene and path seed");
  cli.option("--frames", "N", &cfg.trajectory.frames, "number of frames");
  cli.custom(
         "--trajectory", {"T"},
         [&](const std::vector<std::string>& v) {
           cfg.trajectory.type = trajectory_type_from_string(v[0]);
         },
         "walk | orbit | pan | robot (a wheeled base with the camera on --mount)")
      .shown_default(to_string(cfg.trajectory.type));
  cli.option("--speed", "M", &cfg.trajectory.speed, "metres per frame (peak speed for pan)");
  cli.option("--yaw-rate", "DEG", &cfg.trajectory.max_yaw_rate_deg,
             "max turn per frame for walk/pan/robot");
  cli.option("--width", "W", &width, "image width").min(1);
  cli.option("--height", "H", &height, "image height").min(1);
  cli.option("--hfov", "DEG", &hfov, "horizontal field of view, which gives the intrinsics");
  cli.option("--fx", "F", &fx, "explicit focal length x (pixels)").shown_default("from --hfov");
  cli.option("--fy", "F", &fy, "explicit focal length y (pixels)")
      .shown_default("--fx, else from --hfov");
  cli.option("--cx", "C", &cx, "explicit principal point x (pixels)").shown_default("from --hfov");
  cli.option("--cy", "C", &cy, "explicit principal point y (pixels)").shown_default("from --hfov");
  cli.option("--fps", "F", &cfg.fps, "frame rate for timestamps");
  cli.option("--image-every", "N", &image_every,
             "images of every N-th frame only (a camera slower than the path); the ground "
             "truth keeps every frame")
      .min(1);
  cli.option("--clearance", "M", &cfg.trajectory.clearance, "min camera distance to any surface");
  CameraMount& mount = cfg.trajectory.mount;
  cli.custom(
         "--mount", {"X", "Y", "Z", "PITCH"},
         [&](const std::vector<std::string>& v) {
           mount.x = long3r::parse_cli_value<double>("--mount", v[0]);
           mount.y = long3r::parse_cli_value<double>("--mount", v[1]);
           mount.z = long3r::parse_cli_value<double>("--mount", v[2]);
           mount.pitch_deg = long3r::parse_cli_value<double>("--mount", v[3]);
         },
         "robot: camera_link in base_link (m) and its downward pitch (deg)")
      .shown_default("0.2 0 1.3 12");
  cli.custom(
         "--objects", {"MIN", "MAX"},
         [&](const std::vector<std::string>& v) {
           cfg.scene.min_objects = long3r::parse_cli_value<int>("--objects", v[0]);
           cfg.scene.max_objects = long3r::parse_cli_value<int>("--objects", v[1]);
         },
         "furniture count range")
      .shown_default(std::to_string(cfg.scene.min_objects) + " " +
                     std::to_string(cfg.scene.max_objects));
  cli.section("camera effects (all off by default)");
  LensDistortion& lens = cfg.distortion;
  cli.custom(
         "--distortion", {"K1", "K2", "P1", "P2", "K3"},
         [&](const std::vector<std::string>& v) {
           double* d[] = {&lens.k1, &lens.k2, &lens.p1, &lens.p2, &lens.k3};
           for (int i = 0; i < 5; ++i)
             *d[i] = long3r::parse_cli_value<double>("--distortion", v[i]);
         },
         "plumb_bob lens distortion (OpenCV's k1 k2 p1 p2 k3) of the rendered camera")
      .shown_default("none");
  SensorConfig& sensor = cfg.sensor;
  cli.option("--read-noise", "SIGMA", &sensor.read_noise, "Gaussian read noise (8-bit levels)")
      .min(0);
  cli.option("--shot-noise", "K", &sensor.shot_noise,
             "shot noise: variance K * level added (8-bit levels)")
      .min(0);
  cli.option("--exposure-drift", "F", &sensor.exposure_drift,
             "slow exposure gain drift within 1 +- F (seconds-long waves)")
      .min(0)
      .max(0.95);
  cli.custom(
         "--exposure-steps", {"P", "S"},
         [&](const std::vector<std::string>& v) {
           sensor.exposure_step_prob = long3r::parse_cli_value<double>("--exposure-steps", v[0]);
           sensor.exposure_step = long3r::parse_cli_value<double>("--exposure-steps", v[1]);
         },
         "per frame, with probability P, a new exposure step in [1/(1+S), 1+S]")
      .shown_default("0 0");
  cli.flag("--mono", &sensor.mono, "grey images (mono8)");
  cli.section("run");
  cli.option("--threads", "N", &ropt.threads, "render threads").min(1);
  cli.option("--supersample", "N", &ropt.supersample, "N x N colour rays per pixel").min(1);
  cli.flag("--quiet", &quiet, "no progress output");
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  try {
    cfg.intrinsics = long3r::PinholeIntrinsics::from_hfov(width, height, hfov);
    if (fx > 0) cfg.intrinsics.fx = fx;
    if (fy > 0)
      cfg.intrinsics.fy = fy;
    else if (fx > 0)
      cfg.intrinsics.fy = fx;
    if (cx >= 0) cfg.intrinsics.cx = cx;
    if (cy >= 0) cfg.intrinsics.cy = cy;
  } catch (const std::exception& e) {
    return cli.usage_error(e.what());
  }

  try {
    const auto t0 = std::chrono::steady_clock::now();
    const Sequence seq = generate_sequence(cfg);
    const auto t1 = std::chrono::steady_clock::now();
    if (!quiet) {
      std::printf("room %.2f x %.2f x %.2f m, %zu shapes, %s path of %d frames\n",
                  seq.scene.room_size.x(), seq.scene.room_size.y(), seq.scene.room_size.z(),
                  seq.scene.shapes.size(), to_string(cfg.trajectory.type), cfg.trajectory.frames);
    }
    const WriteStats st = write_tum_sequence(
        seq, out, ropt,
        [&](int i, int n) {
          if (!quiet && (i % 50 == 0 || i == n)) {
            std::printf("\rframe %d / %d", i, n);
            std::fflush(stdout);
          }
        },
        image_every);
    const auto t2 = std::chrono::steady_clock::now();
    const double gen = std::chrono::duration<double>(t1 - t0).count();
    const double total = std::chrono::duration<double>(t2 - t0).count();
    if (!quiet) std::printf("\n");
    std::printf(
        "wrote %d frames %dx%d to %s in %.2f s (scene+path %.2f s, render %.2f s, png+io %.2f s; "
        "%.1f frames/s)\n",
        st.frames, cfg.intrinsics.width, cfg.intrinsics.height, out.c_str(), total, gen,
        st.render_seconds, st.write_seconds, st.frames / std::max(total, 1e-9));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_synth: %s\n", e.what());
    return 1;
  }
  return 0;
}
