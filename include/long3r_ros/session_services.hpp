// SessionServices: the node's services on its session: ~reset, ~pause,
// ~resume, ~save_map, ~save_session, ~load_session and ~save_trajectory.
// Each responds with what was done (counts, frames, the file), or why not.
//
// They run on roscpp's callback threads beside the worker, and reach the
// session only through the node (Node), which holds session_mutex_ around
// every call; a file is written outside that lock where what it holds is a
// copy (the map, the trajectory). Frames: the map and the trajectory (of the
// body: base_frame, else the camera) in map_frame.
#pragma once

#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <cstdint>
#include <functional>
#include <string>

#include "long3r/mapping/voxel_map.hpp"
#include "long3r/pipeline/live_session.hpp"
#include "long3r_ros/LoadSession.h"
#include "long3r_ros/SaveMap.h"
#include "long3r_ros/SaveMesh.h"
#include "long3r_ros/SaveSession.h"
#include "long3r_ros/SaveTrajectory.h"
#include "long3r_ros/robot_frames.hpp"

namespace long3r_ros {

class SessionServices {
 public:
  using Reader = std::function<void(const long3r::LiveSession& session, const RobotFrames& frames)>;
  using Changer = std::function<void(long3r::LiveSession& session)>;

  // What the services ask of the node.
  class Node {
   public:
    virtual ~Node() = default;
    // Runs f under session_mutex_.
    virtual void readSession(const Reader& f) = 0;
    // Runs f under session_mutex_, then refreshes the node's status snapshot.
    virtual void changeSession(const Changer& f) = 0;
    // The last session file saved or loaded ("saved to PATH"), for the
    // diagnostics; called inside changeSession().
    virtual void sessionFileChanged(const std::string& what) = 0;
    // Drops the frames queued for a stream that ended.
    virtual void clearQueue() = 0;
    // Pauses (frames are dropped and counted as they arrive) or resumes;
    // returns whether it was paused.
    virtual bool setPaused(bool paused) = 0;
    virtual std::uint64_t pausedDrops() const = 0;  // frames dropped while paused, in all
    // The whole map as ~map shows it, in map_frame (locks itself).
    virtual long3r::MapSnapshot mapSnapshot() = 0;
    // The fused surface's mesh as ~mesh shows it, in map_frame (empty
    // without surface_enabled).
    virtual long3r::ColoredMesh surfaceMesh() = 0;
  };

  // Advertises on pnh; `log_name`: the nodelet's logger.
  // surface: surface_enabled, which adds ~save_mesh.
  SessionServices(ros::NodeHandle& pnh, std::string map_frame, std::string log_name, Node& node,
                  bool surface);
  void shutdown();  // no callback runs after it returns

 private:
  bool reset(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool pause(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool resume(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool saveMap(SaveMap::Request& req, SaveMap::Response& res);
  bool saveMesh(SaveMesh::Request& req, SaveMesh::Response& res);
  bool saveSession(SaveSession::Request& req, SaveSession::Response& res);
  bool loadSession(LoadSession::Request& req, LoadSession::Response& res);
  bool saveTrajectory(SaveTrajectory::Request& req, SaveTrajectory::Response& res);

  const std::string map_frame_, log_name_;
  Node& node_;
  ros::ServiceServer reset_srv_, pause_srv_, resume_srv_, save_map_srv_, save_trajectory_srv_;
  ros::ServiceServer save_mesh_srv_;
  ros::ServiceServer save_session_srv_, load_session_srv_;
};

}  // namespace long3r_ros
