// long3r_eval: the paper's trajectory (ATE, RPE) and reconstruction (accuracy,
// completion, normal consistency) metrics on TUM-format data; writes a JSON,
// prints a table and draws plots. See docs/evaluation.md.
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>

#include "long3r/config/cli_options.hpp"
#include "long3r/dataset/image_file.hpp"
#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/eval/eval.hpp"
#include "long3r/eval/eval_json.hpp"
#include "long3r/geometry/cv/point_cloud_io.hpp"
#include "long3r/io/atomic_file.hpp"

namespace {

nlohmann::json sim3_json(const long3r::Sim3& s) {
  nlohmann::json r = nlohmann::json::array();
  for (int i = 0; i < 3; ++i) r.push_back({s.rotation(i, 0), s.rotation(i, 1), s.rotation(i, 2)});
  return {{"scale", s.scale},
          {"rotation", r},
          {"translation", {s.translation.x(), s.translation.y(), s.translation.z()}}};
}

}  // namespace

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  using namespace long3r;
  std::string gt_dir, gt_traj_path, gt_cloud_path, est_traj_path, est_map_path,
      out_dir = "eval_out";
  std::string calib, map_align, corr_pred, corr_gt;
  TrajectoryEvalOptions topt;
  ReconstructionEvalOptions ropt;
  GroundTruthCloudOptions gopt;
  double voxel = 0.0, plot_max = 0.1;
  bool save_aligned = false, save_gt_cloud = false;
  CliOptions cli("long3r_eval",
                 "Give --est-traj and/or --est-map (or --save-gt-cloud alone); the reference is "
                 "--gt DIR or --gt-traj / --gt-cloud.");
  cli.section("inputs");
  cli.option("--gt", "DIR", &gt_dir, "TUM-layout folder (groundtruth.txt, depth, calibration.txt)");
  cli.option("--gt-traj", "FILE", &gt_traj_path, "reference trajectory")
      .shown_default("DIR/groundtruth.txt");
  cli.option("--gt-cloud", "FILE", &gt_cloud_path,
             "reference cloud (.ply/.pcd/.xyz) instead of DIR's depth maps");
  cli.option("--est-traj", "FILE", &est_traj_path, "estimated trajectory, TUM format");
  cli.option("--est-map", "FILE", &est_map_path, "estimated map (.ply/.pcd/.xyz)");
  cli.option("--calib", "'fx fy cx cy'", &calib, "intrinsics when DIR has no calibration.txt");
  cli.section("trajectory");
  cli.option("--max-diff", "S", &topt.max_diff, "association tolerance, seconds (as evo)");
  cli.option("--offset", "S", &topt.offset, "added to the estimate's stamps");
  cli.option("--delta", "N", &topt.rpe_delta, "RPE delta in frames");
  cli.flag("--all-pairs", &topt.rpe_all_pairs, "RPE over all pairs (i, i+N), not consecutive ones");
  cli.flag("--no-align", &topt.align, "no alignment", false);
  cli.flag("--no-scale", &topt.correct_scale, "SE(3) instead of Sim(3)", false);
  cli.section("reconstruction");
  cli.option("--map-align", "MODE", &map_align, "initial alignment of the map")
      .choices({"traj", "none", "corr"})
      .shown_default("traj with --est-traj, else none");
  cli.option("--corr-pred", "F", &corr_pred, "corresponding points for --map-align corr");
  cli.option("--corr-gt", "F", &corr_gt, "their counterparts in the GT");
  cli.flag("--no-icp", &ropt.icp, "skip the ICP refinement (default: rigid point-to-point)", false);
  cli.option("--icp-threshold", "M", &ropt.icp_options.max_correspondence_distance,
             "ICP max correspondence distance");
  cli.flag("--icp-scale", &ropt.icp_options.estimate_scale, "let ICP refine the scale too");
  cli.option("--gt-frame-step", "N", &gopt.frame_step, "GT cloud from every N-th frame");
  cli.option("--gt-pixel-step", "N", &gopt.pixel_step, "and every N-th pixel");
  cli.option("--max-depth", "M", &gopt.max_depth, "ignore GT depth beyond M metres")
      .shown_default("none");
  cli.option("--voxel", "M", &voxel, "voxel-downsample both clouds first (0 = off)");
  cli.flag("--no-normals", &ropt.metrics.normals, "skip normal consistency", false);
  cli.section("output");
  cli.option("--out", "DIR", &out_dir, "metrics.json, trajectory.png, map_error.png");
  cli.option("--plot-max-error", "M", &plot_max, "colour scale of map_error.png");
  cli.flag("--save-aligned", &save_aligned, "also write the aligned prediction as map_aligned.ply");
  cli.flag("--save-gt-cloud", &save_gt_cloud,
           "write the GT cloud used as gt_cloud.ply (also without --est-map)");
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  try {
    if (gt_traj_path.empty() && !gt_dir.empty())
      gt_traj_path = (fs::path(gt_dir) / "groundtruth.txt").string();
    if (est_traj_path.empty() && est_map_path.empty() && !save_gt_cloud) {
      throw std::invalid_argument("nothing to evaluate: give --est-traj and/or --est-map");
    }
    if (map_align.empty()) map_align = est_traj_path.empty() ? "none" : "traj";
  } catch (const std::exception& e) {
    return cli.usage_error(e.what());
  }

  try {
    fs::create_directories(out_dir);
    nlohmann::json js;
    std::optional<TrajectoryMetrics> tm;
    Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
    std::printf("%-28s %12s\n", "metric", "value");

    if (!est_traj_path.empty()) {
      if (gt_traj_path.empty()) throw std::invalid_argument("--est-traj needs --gt or --gt-traj");
      const PoseTrajectory ref = read_tum_trajectory(gt_traj_path);
      const PoseTrajectory est = read_tum_trajectory(est_traj_path);
      tm = evaluate_trajectory(ref, est, topt);
      up = estimate_up_axis(tm->ref);
      js["trajectory"] = {
          {"reference", gt_traj_path},
          {"estimate", est_traj_path},
          {"poses_reference", ref.size()},
          {"poses_estimate", est.size()},
          {"matched", tm->matched},
          {"max_diff_s", topt.max_diff},
          {"alignment",
           topt.align ? (topt.correct_scale ? "sim3_umeyama" : "se3_umeyama") : "none"},
          {"sim3", sim3_json(tm->alignment)},
          {"ate_m", tm->ate},
          {"rpe_delta_frames", topt.rpe_delta},
          {"rpe_pairs", topt.rpe_all_pairs ? "all" : "consecutive"},
          {"rpe_translation_m", tm->rpe_translation},
          {"rpe_rotation_deg", tm->rpe_rotation_deg}};
      std::printf("%-28s %12zu\n", "poses matched", tm->matched);
      std::printf("%-28s %12.6f\n", "alignment scale", tm->alignment.scale);
      std::printf("%-28s %12.4f\n", "ATE RMSE [cm]", 100.0 * tm->ate.rmse);
      std::printf("%-28s %12.4f\n", "RPE trans RMSE [cm]", 100.0 * tm->rpe_translation.rmse);
      std::printf("%-28s %12.4f\n", "RPE rot RMSE [deg]", tm->rpe_rotation_deg.rmse);
      std::printf("%-28s %12.4f\n", "RPE trans mean [cm]", 100.0 * tm->rpe_translation.mean);
      std::printf("%-28s %12.4f\n", "RPE rot mean [deg]", tm->rpe_rotation_deg.mean);
      std::vector<Eigen::Vector3d> rp, ep;
      for (size_t i = 0; i < tm->ref.size(); ++i) {
        rp.push_back(tm->ref[i].translation());
        ep.push_back(tm->est_aligned[i].translation());
      }
      char title[160];
      std::snprintf(title, sizeof(title), "ATE %.2f cm  RPE %.2f cm / %.2f deg (delta %d)",
                    100.0 * tm->ate.rmse, 100.0 * tm->rpe_translation.rmse,
                    tm->rpe_rotation_deg.rmse, topt.rpe_delta);
      write_image_atomically((fs::path(out_dir) / "trajectory.png").string(),
                             plot_trajectory_top_view(rp, ep, up, title));
    }

    std::vector<Eigen::Vector3f> gt_cloud;
    if (!est_map_path.empty() || save_gt_cloud) {
      if (!gt_cloud_path.empty()) {
        gt_cloud = load_point_cloud(gt_cloud_path);
      } else {
        if (gt_dir.empty()) throw std::invalid_argument("--est-map needs --gt DIR or --gt-cloud");
        TumDatasetOptions dopt;
        dopt.require_depth = true;
        dopt.require_pose = true;
        const TumDataset ds = TumDataset::open(gt_dir, dopt);
        PinholeIntrinsics k;
        if (!calib.empty()) {
          std::istringstream ss(calib);
          if (!(ss >> k.fx >> k.fy >> k.cx >> k.cy)) throw std::invalid_argument("bad --calib");
        } else if (ds.calibration()) {
          k = *ds.calibration();
        } else {
          throw std::invalid_argument(gt_dir + " has no calibration.txt; pass --calib");
        }
        gt_cloud = ground_truth_cloud(ds, k, gopt);
        if (!tm) up = estimate_up_axis(ds.frame_trajectory().poses);
      }
      if (voxel > 0) gt_cloud = voxel_downsample(gt_cloud, voxel);
      if (save_gt_cloud) {
        save_point_cloud((fs::path(out_dir) / "gt_cloud.ply").string(), gt_cloud);
        std::printf("%-28s %12zu\n", "GT cloud points (saved)", gt_cloud.size());
      }
    }
    if (!est_map_path.empty()) {
      std::vector<Eigen::Vector3f> pred = load_point_cloud(est_map_path);
      if (voxel > 0) pred = voxel_downsample(pred, voxel);
      if (map_align == "traj") {
        if (!tm) throw std::invalid_argument("--map-align traj needs --est-traj");
        ropt.initial = tm->alignment;
      } else if (map_align == "corr") {
        if (corr_pred.empty() || corr_gt.empty()) {
          throw std::invalid_argument("--map-align corr needs --corr-pred and --corr-gt");
        }
        ropt.initial =
            align_correspondences(load_point_cloud(corr_pred), load_point_cloud(corr_gt), true);
      }
      const ReconstructionEvalResult rr = evaluate_reconstruction(pred, gt_cloud, ropt);
      const ReconstructionMetrics& m = rr.metrics;
      js["reconstruction"] = {
          {"prediction", est_map_path},
          {"points_prediction", m.num_pred},
          {"points_gt", m.num_gt},
          {"voxel_m", voxel},
          {"initial_alignment", map_align},
          {"icp", ropt.icp ? (ropt.icp_options.estimate_scale ? "sim3_point_to_point"
                                                              : "rigid_point_to_point")
                           : "none"},
          {"icp_threshold_m", ropt.icp_options.max_correspondence_distance},
          {"icp_fitness", rr.icp ? rr.icp->fitness : 0.0},
          {"icp_iterations", rr.icp ? rr.icp->iterations : 0},
          {"sim3", sim3_json(rr.alignment)},
          {"accuracy_mean_m", m.accuracy_mean},
          {"accuracy_median_m", m.accuracy_median},
          {"completion_mean_m", m.completion_mean},
          {"completion_median_m", m.completion_median},
          {"completion_ratio", m.completion_ratio},
          {"completion_ratio_threshold_m", ropt.metrics.completion_ratio_threshold}};
      if (ropt.metrics.normals) {
        js["reconstruction"]["nc_mean"] = m.nc_mean;
        js["reconstruction"]["nc_median"] = m.nc_median;
        js["reconstruction"]["nc_accuracy_mean"] = m.nc_accuracy_mean;
        js["reconstruction"]["nc_accuracy_median"] = m.nc_accuracy_median;
        js["reconstruction"]["nc_completion_mean"] = m.nc_completion_mean;
        js["reconstruction"]["nc_completion_median"] = m.nc_completion_median;
        js["reconstruction"]["normal_neighbours"] = ropt.metrics.normal_neighbours;
      }
      std::printf("%-28s %12zu\n", "points pred / GT", m.num_pred);
      std::printf("%-28s %12zu\n", "", m.num_gt);
      std::printf("%-28s %12.4f\n", "Acc mean [cm]", 100.0 * m.accuracy_mean);
      std::printf("%-28s %12.4f\n", "Acc median [cm]", 100.0 * m.accuracy_median);
      std::printf("%-28s %12.4f\n", "Comp mean [cm]", 100.0 * m.completion_mean);
      std::printf("%-28s %12.4f\n", "Comp median [cm]", 100.0 * m.completion_median);
      if (ropt.metrics.normals) {
        std::printf("%-28s %12.4f\n", "NC mean", m.nc_mean);
        std::printf("%-28s %12.4f\n", "NC median", m.nc_median);
      }
      std::printf("%-28s %12.4f\n", "Comp ratio (<5cm)", m.completion_ratio);
      write_image_atomically((fs::path(out_dir) / "map_error.png").string(),
                             plot_error_top_view(rr.pred_aligned, m.accuracy_errors, gt_cloud,
                                                 m.completion_errors, up, plot_max));
      if (save_aligned)
        save_point_cloud((fs::path(out_dir) / "map_aligned.ply").string(), rr.pred_aligned);
    }
    const std::string json_path = (fs::path(out_dir) / "metrics.json").string();
    write_file_atomically(json_path, js.dump(2) + "\n");
    std::printf("wrote %s\n", json_path.c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_eval: %s\n", e.what());
    return 1;
  }
  return 0;
}
