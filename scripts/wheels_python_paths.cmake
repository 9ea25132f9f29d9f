# Loaded into the build of interfaces/simulation_interfaces by scripts/build_interfaces.sh, as
# CMAKE_PROJECT_INCLUDE, so that the package's own CMakeLists.txt stays the standard one.
#
# The ros-jazzy-* wheels were built in a manylinux container whose Python lives in
# /opt/python/cp312-cp312. Their exported CMake targets (the <pkg>__rosidl_generator_py ones)
# name that container's Python and numpy include folders, which do not exist here, and CMake
# refuses imported targets with missing include folders. At the end of the configure step every
# such folder is swapped for the one of the interpreter this build uses (Python3_EXECUTABLE);
# any other path under the container's prefix stops the build with its name instead of being
# guessed at. Where no target names the container (a sourced ROS 2), nothing changes.
set(_wheels_build_prefix /opt/python/cp312-cp312)

if(NOT Python3_EXECUTABLE)
  message(FATAL_ERROR "wheels_python_paths.cmake needs -DPython3_EXECUTABLE=<the venv's python>")
endif()
execute_process(
  COMMAND "${Python3_EXECUTABLE}" -c
    "import sysconfig, numpy; print(sysconfig.get_path('include')); print(numpy.get_include())"
  OUTPUT_VARIABLE _this_python_includes
  RESULT_VARIABLE _this_python_result
  OUTPUT_STRIP_TRAILING_WHITESPACE)
if(NOT _this_python_result EQUAL 0)
  message(FATAL_ERROR "${Python3_EXECUTABLE} cannot name its include folders (is numpy installed?)")
endif()
string(REPLACE "\n" ";" _this_python_includes "${_this_python_includes}")
list(GET _this_python_includes 0 _this_python_include)
list(GET _this_python_includes 1 _this_numpy_include)

function(_point_wheel_targets_at_this_python)
  get_property(targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT dirs)
      continue()
    endif()
    set(fixed)
    foreach(dir IN LISTS dirs)
      if(dir MATCHES "^${_wheels_build_prefix}/.*/numpy/_core/include$")
        list(APPEND fixed "${_this_numpy_include}")
      elseif(dir MATCHES "^${_wheels_build_prefix}/include/python3\\.12$")
        list(APPEND fixed "${_this_python_include}")
      elseif(dir MATCHES "^${_wheels_build_prefix}/")
        message(FATAL_ERROR "${target} names ${dir} of the wheels' build machine; "
          "scripts/wheels_python_paths.cmake does not know what stands for it here")
      else()
        list(APPEND fixed "${dir}")
      endif()
    endforeach()
    if(NOT fixed STREQUAL dirs)
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${fixed}")
    endif()
  endforeach()
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _point_wheel_targets_at_this_python)
