# package.xml declares every dependency under a rosdep key that
# rosdep/long3r_ros.yaml maps to installed Debian packages.
add_test(NAME rosdep_keys COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/scripts/rosdep_keys_test.py)
