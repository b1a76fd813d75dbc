# Command-line and bag tests of the scene generator and the evaluation tools
# (python drivers; they need the OpenCV/PCL/Eigen tools).
if(TARGET app_long3r_synth AND TARGET app_long3r_eval)
  add_test(NAME synth_eval_cli
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/synth/synth_eval_cli_test.py
      --synth $<TARGET_FILE:app_long3r_synth> --eval $<TARGET_FILE:app_long3r_eval>
      --workdir ${PROJECT_BINARY_DIR}/test_tmp/synth_eval_cli)

  # scripts/tum_to_bag.py needs Debian's python3-rosbag (no ROS workspace).
  execute_process(COMMAND /usr/bin/python3 -c "import rosbag, genpy, genmsg, numpy"
    RESULT_VARIABLE LONG3R_PY_ROSBAG_RC OUTPUT_QUIET ERROR_QUIET)
  if(LONG3R_PY_ROSBAG_RC EQUAL 0)
    add_test(NAME synth_tum_to_bag
      COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/synth/tum_to_bag_test.py
        --synth $<TARGET_FILE:app_long3r_synth> --script ${PROJECT_SOURCE_DIR}/scripts/tum_to_bag.py
        --workdir ${PROJECT_BINARY_DIR}/test_tmp/tum_to_bag)
    # Robot-like bags (TF tree, odometry, distortion, compressed images; Pillow for the latter).
    add_test(NAME synth_tum_to_bag_robot
      COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/synth/tum_to_bag_robot_test.py
        --synth $<TARGET_FILE:app_long3r_synth> --script ${PROJECT_SOURCE_DIR}/scripts/tum_to_bag.py
        --workdir ${PROJECT_BINARY_DIR}/test_tmp/tum_to_bag_robot)
    # rosbag play latches the robot bag's /tf_static for a late tf2 listener
    # (its own rosmaster on a free port).
    execute_process(COMMAND /usr/bin/python3 -c "import rospy, tf2_ros"
      RESULT_VARIABLE LONG3R_PY_TF2_RC OUTPUT_QUIET ERROR_QUIET)
    find_program(LONG3R_ROSMASTER rosmaster)
    find_program(LONG3R_ROSBAG rosbag)
    if(LONG3R_PY_TF2_RC EQUAL 0 AND LONG3R_ROSMASTER AND LONG3R_ROSBAG)
      add_test(NAME synth_tf_static_latch
        COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/synth/tf_static_latch_test.py
          --synth $<TARGET_FILE:app_long3r_synth> --script ${PROJECT_SOURCE_DIR}/scripts/tum_to_bag.py
          --workdir ${PROJECT_BINARY_DIR}/test_tmp/tf_static_latch)
    else()
      message(STATUS "long3r: rospy/tf2_ros, rosmaster or rosbag missing; skipping synth_tf_static_latch")
    endif()
  else()
    message(STATUS "long3r: python rosbag not importable; skipping the synth_tum_to_bag test")
  endif()
endif()
