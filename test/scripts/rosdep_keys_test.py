#!/usr/bin/python3
"""package.xml declares what the build uses, and rosdep can install it:

  * every library CMakeLists.txt looks for (find_package, and nanoflann's
    header) has its rosdep key in package.xml;
  * every key package.xml names is in rosdep/long3r_ros.yaml with Debian
    packages, and on a Debian machine each of those is a real, installed
    package (scripts/install_deps.sh installed them), so the mapping is not
    a guess;
  * every key of the yaml file is used (no stale entries);
  * every rule has rosdep's form: a platform (debian or ubuntu) mapped to a
    list of package names, or to codenames each mapped to such a list.
"""
import os
import re
import subprocess
import sys
import unittest
import xml.etree.ElementTree as ET

import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEPEND_TAGS = ('depend', 'build_depend', 'build_export_depend', 'exec_depend', 'test_depend',
               'buildtool_depend')
# find_package / find_path name in CMakeLists.txt -> its rosdep key.
CMAKE_KEYS = {'Torch': 'libtorch-dev', 'nlohmann_json': 'nlohmann-json-dev', 'Eigen3': 'eigen',
              'OpenCV': 'libopencv-dev', 'PCL': 'libpcl-all-dev',
              'LONG3R_NANOFLANN_DIR': 'libnanoflann-dev', 'LONG3R_EIGEN_DIR': 'eigen',
              'LONG3R_NLOHMANN_JSON_DIR': 'nlohmann-json-dev', 'catkin': 'catkin', 'rostest': 'rostest',
              'roslaunch': 'roslaunch', 'LONG3R_GLOO_INCLUDE_DIR': 'libgloo-dev',
              'Open3D': 'libopen3d-dev', 'octomap': 'liboctomap-dev'}
# CMake's own modules: nothing to install. NCCL's header comes with a CUDA
# libtorch (its NCCL), never from Debian's packages.
CMAKE_BUILTIN = {'Threads', 'Python3', 'GTest', 'LONG3R_NCCL_INCLUDE_DIR'}


def package_keys():
    root = ET.parse(os.path.join(ROOT, 'package.xml')).getroot()
    return {e.text.strip() for tag in DEPEND_TAGS for e in root.findall(tag)}


def rosdep_yaml():
    with open(os.path.join(ROOT, 'rosdep', 'long3r_ros.yaml')) as f:
        return yaml.safe_load(f)


def installed(package):
    r = subprocess.run(['dpkg-query', '-W', '-f', '${Status}', package],
                       stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    return r.returncode == 0 and r.stdout.strip().endswith('installed')


PLATFORMS = {'debian': {'bookworm', 'bullseye', 'buster'}, 'ubuntu': {'focal', 'jammy'}}
PACKAGE_NAME = re.compile(r'^[a-z0-9][a-z0-9+.-]+$')


class RosdepKeys(unittest.TestCase):
    def test_every_rule_has_rosdeps_form(self):
        for key, rule in rosdep_yaml().items():
            self.assertIsInstance(rule, dict, key)
            for platform, packages in rule.items():
                self.assertIn(platform, PLATFORMS, '%s: platform %s' % (key, platform))
                by_codename = packages if isinstance(packages, dict) else {None: packages}
                for codename, names in by_codename.items():
                    if codename is not None:
                        self.assertIn(codename, PLATFORMS[platform], '%s: %s %s' % (key, platform, codename))
                    self.assertIsInstance(names, list, '%s: %s' % (key, platform))
                    self.assertTrue(names, '%s: %s lists no package' % (key, platform))
                    for name in names:
                        self.assertRegex(name, PACKAGE_NAME, '%s: %s' % (key, platform))

    def test_cmake_dependencies_are_declared(self):
        cmake = open(os.path.join(ROOT, 'CMakeLists.txt')).read()
        cmake += ''.join(open(os.path.join(ROOT, 'cmake', f)).read()
                         for f in os.listdir(os.path.join(ROOT, 'cmake')) if f.endswith('.cmake'))
        found = set(re.findall(r'find_package\((\w+)', cmake))
        found |= set(re.findall(r'find_path\((\w+)', cmake))
        keys = package_keys()
        for name in sorted(found - CMAKE_BUILTIN):
            self.assertIn(name, CMAKE_KEYS, 'find_package(%s) has no rosdep key in this test' % name)
            key = CMAKE_KEYS[name]
            if key == 'roslaunch':  # roslaunch_add_file_check: part of the ROS base
                continue
            self.assertIn(key, keys, 'package.xml does not declare %s (for %s)' % (key, name))
        # The catkin components the build asks for are declared too.
        components = re.search(r'set\(LONG3R_CATKIN_DEPS([^)]*)\)', cmake)
        self.assertIsNotNone(components)
        for c in components.group(1).split():
            self.assertIn(c, keys, 'package.xml does not declare the catkin component ' + c)

    def test_every_key_maps_to_installed_debian_packages(self):
        table = rosdep_yaml()
        keys = package_keys()
        for key in sorted(keys):
            self.assertIn(key, table, 'rosdep/long3r_ros.yaml has no entry for ' + key)
            self.assertIn('debian', table[key], key)
            self.assertTrue(table[key]['debian'], key)
        self.assertEqual(sorted(set(table) - keys), [], 'keys of the yaml file package.xml does not use')
        if not os.path.exists('/usr/bin/dpkg-query'):
            self.skipTest('not a Debian machine')
        for key in sorted(keys):
            for package in table[key]['debian']:
                self.assertTrue(installed(package),
                                '%s -> %s: not an installed Debian package' % (key, package))


if __name__ == '__main__':
    unittest.main(argv=sys.argv[:1])
