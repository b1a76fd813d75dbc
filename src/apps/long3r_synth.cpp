// long3r_synth: renders a procedural indoor sequence with exact ground truth
// into a TUM RGB-D style folder (see include/long3r/synth/synth.hpp, docs/evaluation.md).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <string>

#include "long3r/io/cli_options.hpp"
#include "long3r/synth/synth.hpp"

int main(int argc, char** argv) {
  using namespace long3r::synth;
  SequenceConfig cfg;
  RenderOptions ropt;
  std::string out;
  int width = 224, height = 224;
  double hfov = 70.0, fx = 0, fy = 0, cx = -1, cy = -1;
  bool quiet = false;
  long3r::CliOptions cli("long3r_synth");
  cli.option("--out", "DIR", &out, "the TUM RGB-D style folder to write").required();
  cli.option("--seed", "N", &cfg.seed, "scene and path seed");
  cli.option("--frames", "N", &cfg.trajectory.frames, "number of frames");
  cli.custom(
         "--trajectory", {"T"},
         [&](const std::vector<std::string>& v) {
           cfg.trajectory.type = trajectory_type_from_string(v[0]);
         },
         "walk | orbit | pan")
      .shown_default(to_string(cfg.trajectory.type));
  cli.option("--speed", "M", &cfg.trajectory.speed, "metres per frame (peak speed for pan)");
  cli.option("--yaw-rate", "DEG", &cfg.trajectory.max_yaw_rate_deg,
             "max turn per frame for walk/pan");
  cli.option("--width", "W", &width, "image width").min(1);
  cli.option("--height", "H", &height, "image height").min(1);
  cli.option("--hfov", "DEG", &hfov, "horizontal field of view, which gives the intrinsics");
  cli.option("--fx", "F", &fx, "explicit focal length x (pixels)").shown_default("from --hfov");
  cli.option("--fy", "F", &fy, "explicit focal length y (pixels)")
      .shown_default("--fx, else from --hfov");
  cli.option("--cx", "C", &cx, "explicit principal point x (pixels)").shown_default("from --hfov");
  cli.option("--cy", "C", &cy, "explicit principal point y (pixels)").shown_default("from --hfov");
  cli.option("--fps", "F", &cfg.fps, "frame rate for timestamps");
  cli.option("--clearance", "M", &cfg.trajectory.clearance, "min camera distance to any surface");
  cli.custom(
         "--objects", {"MIN", "MAX"},
         [&](const std::vector<std::string>& v) {
           cfg.scene.min_objects = long3r::parse_cli_value<int>("--objects", v[0]);
           cfg.scene.max_objects = long3r::parse_cli_value<int>("--objects", v[1]);
         },
         "furniture count range")
      .shown_default(std::to_string(cfg.scene.min_objects) + " " +
                     std::to_string(cfg.scene.max_objects));
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
    const WriteStats st = write_tum_sequence(seq, out, ropt, [&](int i, int n) {
      if (!quiet && (i % 50 == 0 || i == n)) {
        std::printf("\rframe %d / %d", i, n);
        std::fflush(stdout);
      }
    });
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
