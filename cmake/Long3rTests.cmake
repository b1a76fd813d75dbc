# Unit tests of the core (gtest), golden parity runs, and (with ROS) rostests.
# Everything registers with ctest; scripts/run_tests.sh runs ctest.
enable_testing()
find_package(GTest REQUIRED)
include(GoogleTest)

# test/core/test_*.cpp: one gtest binary for the core. Each gtest case becomes
# its own ctest entry, so ctest's summary counts individual tests.
file(GLOB LONG3R_CORE_TEST_SRCS CONFIGURE_DEPENDS test/core/test_*.cpp)
if(LONG3R_CORE_TEST_SRCS)
  add_executable(long3r_core_tests ${LONG3R_CORE_TEST_SRCS})
  target_link_libraries(long3r_core_tests PRIVATE long3r_model GTest::gtest GTest::gtest_main)
  target_include_directories(long3r_core_tests PRIVATE ${PROJECT_SOURCE_DIR}/src ${PROJECT_SOURCE_DIR}/test)
  target_compile_options(long3r_core_tests PRIVATE ${LONG3R_WARNINGS})
  target_compile_definitions(long3r_core_tests PRIVATE
    LONG3R_SHARED_DIR="${LONG3R_SHARED_DIR}"
    LONG3R_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    LONG3R_BINARY_DIR="${PROJECT_BINARY_DIR}")
  gtest_discover_tests(long3r_core_tests
    WORKING_DIRECTORY ${PROJECT_BINARY_DIR}
    DISCOVERY_TIMEOUT 60
    PROPERTIES ENVIRONMENT "OMP_NUM_THREADS=2;OPENBLAS_NUM_THREADS=1")
endif()

# test/pipeline/test_*.cpp: gtests of the OpenCV/PCL side of the core.
file(GLOB LONG3R_PIPELINE_TEST_SRCS CONFIGURE_DEPENDS test/pipeline/test_*.cpp)
if(LONG3R_HAVE_CORE_CV AND LONG3R_PIPELINE_TEST_SRCS)
  add_executable(long3r_pipeline_tests ${LONG3R_PIPELINE_TEST_SRCS})
  target_link_libraries(long3r_pipeline_tests PRIVATE long3r_core GTest::gtest GTest::gtest_main)
  target_include_directories(long3r_pipeline_tests PRIVATE ${PROJECT_SOURCE_DIR}/src ${PROJECT_SOURCE_DIR}/test)
  target_compile_options(long3r_pipeline_tests PRIVATE ${LONG3R_WARNINGS})
  target_compile_definitions(long3r_pipeline_tests PRIVATE
    LONG3R_SHARED_DIR="${LONG3R_SHARED_DIR}"
    LONG3R_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    LONG3R_BINARY_DIR="${PROJECT_BINARY_DIR}")
  gtest_discover_tests(long3r_pipeline_tests
    WORKING_DIRECTORY ${PROJECT_BINARY_DIR}
    DISCOVERY_TIMEOUT 60
    PROPERTIES ENVIRONMENT "OMP_NUM_THREADS=2;OPENBLAS_NUM_THREADS=1")
endif()

# Extra test registrations owned by each area (golden parity, fuzz corpus, ...).
file(GLOB LONG3R_TEST_CMAKE CONFIGURE_DEPENDS test/core/*.cmake test/pipeline/*.cmake)
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
  # Users start the launch files by package and name; two files of one name
  # anywhere in the package make that fail ("multiple files named ...").
  foreach(l long3r replay)
    add_test(NAME launch_by_name_${l}
      COMMAND ${CATKIN_ENV} roslaunch --nodes long3r_ros ${l}.launch bag:=replay.bag)
  endforeach()
  file(GLOB LONG3R_ROSTESTS CONFIGURE_DEPENDS test/ros/*.test)
  foreach(t ${LONG3R_ROSTESTS})
    add_rostest(${t})
  endforeach()

  # Nodelet rostests: a fixture generates the bags and a random-weight model.
  set(LONG3R_REPLAY_DATA ${PROJECT_BINARY_DIR}/replay_data)
  add_test(NAME ros_replay_data
    COMMAND ${PROJECT_SOURCE_DIR}/test/ros/make_replay_data.sh
            $<TARGET_FILE_DIR:long3r_synth> ${LONG3R_REPLAY_DATA})
  set_tests_properties(ros_replay_data PROPERTIES FIXTURES_SETUP ros_replay_data)
  foreach(t replay_normal replay_bad smoke)
    set_tests_properties(_ctest_${PROJECT_NAME}_rostest_test_ros_${t}.test PROPERTIES
      FIXTURES_REQUIRED ros_replay_data
      ENVIRONMENT "LONG3R_REPLAY_DATA=${LONG3R_REPLAY_DATA}")
  endforeach()
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
    target_link_libraries(long3r_ros_unit_tests PRIVATE long3r_nodelet GTest::gtest GTest::gtest_main)
    target_compile_options(long3r_ros_unit_tests PRIVATE ${LONG3R_WARNINGS})
    gtest_discover_tests(long3r_ros_unit_tests DISCOVERY_TIMEOUT 60)
  endif()
endif()
