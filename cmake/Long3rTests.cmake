# Unit tests of the core (gtest), golden parity runs, and (with ROS) rostests.
# Everything registers with ctest; scripts/run_tests.sh runs ctest.
enable_testing()
find_package(GTest REQUIRED)
include(GoogleTest)

# Tests live by module (test/<module>/) beside test/support/, the fixtures
# they share (tiny model configurations, synthetic frames and cameras). Two
# gtest binaries, by what they need:
#   long3r_model_tests  test/{config,io,model,memory}: libtorch only (builds
#                       wherever the model does, CUDA libtorch included);
#   long3r_cv_tests     test/{geometry,mapping,pipeline,tracking,dataset,eval,synth,train}: the
#                       Eigen, OpenCV and PCL side.
# Each gtest case becomes its own ctest entry, so ctest's summary counts
# individual tests.
# The shared fixtures, compiled once: long3r_test_support (libtorch only) for
# both binaries, long3r_cv_test_support (OpenCV, Eigen) for the second.
function(long3r_add_test_support name)
  cmake_parse_arguments(ARG "" "" "SOURCES;LIBS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_link_libraries(${name} PUBLIC ${ARG_LIBS} GTest::gtest)
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR}/test)
  target_compile_options(${name} PRIVATE ${LONG3R_WARNINGS})
  target_compile_definitions(${name} PRIVATE LONG3R_BINARY_DIR="${PROJECT_BINARY_DIR}")
endfunction()
long3r_add_test_support(long3r_test_support
  SOURCES test/support/test_support.cpp LIBS long3r_network)
if(LONG3R_HAVE_CV)
  long3r_add_test_support(long3r_cv_test_support
    SOURCES test/support/cv_test_support.cpp
    LIBS long3r_pipeline long3r_synth_cv long3r_train_cv long3r_test_support)
endif()

function(long3r_add_gtest_binary name)
  cmake_parse_arguments(ARG "" "" "FOLDERS;LIBS" ${ARGN})
  set(srcs)
  foreach(folder ${ARG_FOLDERS})
    file(GLOB folder_srcs CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/test/${folder}/test_*.cpp)
    list(APPEND srcs ${folder_srcs})
  endforeach()
  if(NOT srcs)
    return()
  endif()
  add_executable(${name} ${srcs})
  target_link_libraries(${name} PRIVATE ${ARG_LIBS} GTest::gtest GTest::gtest_main)
  target_include_directories(${name} PRIVATE ${PROJECT_SOURCE_DIR}/src ${PROJECT_SOURCE_DIR}/test)
  target_compile_options(${name} PRIVATE ${LONG3R_WARNINGS})
  target_compile_definitions(${name} PRIVATE
    LONG3R_GOLDEN_DIR="${LONG3R_GOLDEN_DIR}"
    LONG3R_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    LONG3R_BINARY_DIR="${PROJECT_BINARY_DIR}")
  gtest_discover_tests(${name}
    WORKING_DIRECTORY ${PROJECT_BINARY_DIR}
    DISCOVERY_TIMEOUT 60
    # One variable only: the discovery writes a list value as separate
    # arguments, which would cut the property list (OPENBLAS_NUM_THREADS
    # comes from scripts/env.sh, whose environment ctest runs in).
    PROPERTIES LABELS unit ENVIRONMENT "OMP_NUM_THREADS=2")
endfunction()

long3r_add_gtest_binary(long3r_model_tests FOLDERS config io model memory
  LIBS long3r_network long3r_test_support)
if(LONG3R_HAVE_CV)
  long3r_add_gtest_binary(long3r_cv_tests
    FOLDERS geometry mapping pipeline tracking dataset eval synth train
    LIBS long3r_train_cv long3r_synth_cv long3r_tracking long3r_mapping long3r_cv_test_support)
endif()

# Extra test registrations owned by each module (golden parity, fuzz corpus,
# command-line drivers, ...).
file(GLOB LONG3R_TEST_CMAKE CONFIGURE_DEPENDS test/*/*.cmake)
foreach(f ${LONG3R_TEST_CMAKE})
  include(${f})
endforeach()

# Style: every C++ file is clang-formatted (skipped where clang-format is absent).
find_program(LONG3R_CLANG_FORMAT clang-format)
if(LONG3R_CLANG_FORMAT)
  add_test(NAME clang_format COMMAND ${PROJECT_SOURCE_DIR}/scripts/format.sh --check)
endif()

if(LONG3R_WITH_ROS)
  find_package(rostest REQUIRED)
  find_package(roslaunch REQUIRED)
  roslaunch_add_file_check(launch/long3r.launch)
  roslaunch_add_file_check(launch/replay.launch bag:=replay.bag)
  roslaunch_add_file_check(launch/realsense.launch)
  roslaunch_add_file_check(launch/usb_camera.launch)
  # Users start the launch files by package and name; two files of one name
  # anywhere in the package make that fail ("multiple files named ...").
  foreach(l long3r replay realsense usb_camera)
    add_test(NAME launch_by_name_${l}
      COMMAND ${CATKIN_ENV} roslaunch --nodes long3r_ros ${l}.launch bag:=replay.bag)
  endforeach()
  # The launch files keep the user's config file (roslaunch --dump-params).
  add_test(NAME ros_launch_params
    COMMAND ${CATKIN_ENV} /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/ros/launch_params.py)
  file(GLOB LONG3R_ROSTESTS CONFIGURE_DEPENDS test/ros/*.test)
  foreach(t ${LONG3R_ROSTESTS})
    add_rostest(${t})
  endforeach()

  # A nodelet that cannot start ends the launch, naming the reason.
  add_test(NAME ros_startup_faults
    COMMAND ${CATKIN_ENV} /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/ros/startup_faults.py)

  # Nodelet rostests: a fixture generates the bags and a random-weight model.
  set(LONG3R_REPLAY_DATA ${PROJECT_BINARY_DIR}/replay_data)
  add_test(NAME ros_replay_data
    COMMAND ${PROJECT_SOURCE_DIR}/test/ros/make_replay_data.sh
            $<TARGET_FILE_DIR:app_long3r_synth> ${LONG3R_REPLAY_DATA})
  set_tests_properties(ros_replay_data PROPERTIES FIXTURES_SETUP ros_replay_data)
  foreach(t replay_normal replay_bad replay_pause replay_slow replay_compressed replay_lost
          live_input smoke
          robot_odometry robot_depth robot_keyframes_depth robot_undistorted robot_distorted
          robot_pnp_fails robot_keyframes_odometry_prior)
    set_tests_properties(_ctest_${PROJECT_NAME}_rostest_test_ros_${t}.test PROPERTIES
      FIXTURES_REQUIRED ros_replay_data
      ENVIRONMENT "LONG3R_REPLAY_DATA=${LONG3R_REPLAY_DATA};LONG3R_BIN=$<TARGET_FILE_DIR:app_long3r_eval>")
  endforeach()
  # Sessions: map, stop, restart, continue in the same map frame (three node runs).
  add_test(NAME ros_sessions
    COMMAND ${CATKIN_ENV} /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/ros/session_check.py)
  set_tests_properties(ros_sessions PROPERTIES FIXTURES_REQUIRED ros_replay_data
    ENVIRONMENT "LONG3R_REPLAY_DATA=${LONG3R_REPLAY_DATA}" TIMEOUT 900)
  # Cold starts of a robot-like replay, each posing every frame (by hand:
  # test/ros/replay_stress.py --runs 20).
  add_test(NAME ros_replay_stress
    COMMAND ${CATKIN_ENV} /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/ros/replay_stress.py
            --bag ${LONG3R_REPLAY_DATA}/robot.bag --frames 40 --runs 3
            --work ${PROJECT_BINARY_DIR}/test_tmp/replay_stress)
  set_tests_properties(ros_replay_stress PROPERTIES FIXTURES_REQUIRED ros_replay_data TIMEOUT 1800)
  # The install space on its own: the package, its launch files and the demo.
  add_test(NAME ros_install_space
    COMMAND ${PROJECT_SOURCE_DIR}/test/ros/install_space_check.sh ${CMAKE_BINARY_DIR}
            ${LONG3R_REPLAY_DATA} ${PROJECT_BINARY_DIR}/test_tmp/install_space)
  set_tests_properties(ros_install_space PROPERTIES FIXTURES_REQUIRED ros_replay_data TIMEOUT 900)
  # The distorted camera's map is as accurate as the undistorted one's (within 5 %).
  foreach(t robot_undistorted robot_distorted)
    set_tests_properties(_ctest_${PROJECT_NAME}_rostest_test_ros_${t}.test PROPERTIES
      FIXTURES_SETUP ros_robot_lens)
  endforeach()
  add_test(NAME ros_robot_distortion_accuracy
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/ros/compare_metrics.py
            ${LONG3R_REPLAY_DATA}/robot_undistorted_eval/metrics.json
            ${LONG3R_REPLAY_DATA}/robot_distorted_eval/metrics.json
            --key reconstruction.accuracy_mean_m --max-rel 0.05)
  set_tests_properties(ros_robot_distortion_accuracy PROPERTIES
    FIXTURES_REQUIRED "ros_robot_lens;ros_replay_data")
  file(GLOB LONG3R_ROS_GTEST_SRCS CONFIGURE_DEPENDS test/ros/test_*.cpp)
  foreach(src ${LONG3R_ROS_GTEST_SRCS})
    get_filename_component(name ${src} NAME_WE)
    add_executable(${name} ${src})
    target_link_libraries(${name} PRIVATE long3r_nodelet GTest::gtest)
    target_compile_options(${name} PRIVATE ${LONG3R_WARNINGS})
    add_dependencies(tests ${name})
  endforeach()
  # test/ros/unit_*.cpp: ROS-layer unit tests that need no ROS master.
  file(GLOB LONG3R_ROS_UNIT_SRCS CONFIGURE_DEPENDS test/ros/unit_*.cpp)
  if(LONG3R_ROS_UNIT_SRCS)
    add_executable(long3r_ros_unit_tests ${LONG3R_ROS_UNIT_SRCS})
    target_link_libraries(long3r_ros_unit_tests PRIVATE long3r_nodelet long3r_cv_test_support
      GTest::gtest GTest::gtest_main)
    target_compile_options(long3r_ros_unit_tests PRIVATE ${LONG3R_WARNINGS})
    gtest_discover_tests(long3r_ros_unit_tests DISCOVERY_TIMEOUT 60 PROPERTIES LABELS "unit;ros")
  endif()
endif()

# Labels, so that a tier runs alone (README, "Run every test"):
#   unit         the gtests and the golden parity runs (a few minutes);
#   integration  the command-line drivers, scripts, benchmarks' checks and
#                the shipped model's figures;
#   ros          launch checks and rostests (with a ROS build).
# The gtests carry theirs from gtest_discover_tests above; every other test
# registered in this folder gets one here.
get_property(LONG3R_ALL_TESTS DIRECTORY PROPERTY TESTS)
foreach(t ${LONG3R_ALL_TESTS})
  get_test_property(${t} LABELS labels)
  if(t MATCHES "rostest|roslaunch|^launch_by_name_|^ros_")
    set_property(TEST ${t} APPEND PROPERTY LABELS ros)
  elseif(labels MATCHES "golden" OR t STREQUAL "clang_format")
    set_property(TEST ${t} APPEND PROPERTY LABELS unit)
  else()
    set_property(TEST ${t} APPEND PROPERTY LABELS integration)
  endif()
endforeach()
