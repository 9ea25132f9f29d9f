# Loaded into the builds of scripts/build_interfaces.sh, as CMAKE_PROJECT_INCLUDE_BEFORE, so that
# an interface package generates only what rclpy loads: the C structs (rosidl_generator_c), the
# C typesupports (rosidl_typesupport_c with its introspection and Fast DDS implementations), the
# type descriptions and the Python bindings (rosidl_generator_py). The C++ generator and C++
# typesupports are dropped: nothing in the wheels set-up loads them (no rclcpp, no rosbag2),
# and they were 114 of the 383 files compiled for simulation_interfaces, C++ files with heavy
# headers. The package's own CMakeLists.txt stays the standard one, so colcon or plain cmake
# still build every language.
#
# The C++ packages must still be found (the dependencies' exported CMake configs require them,
# and the Fast DDS C typesupport links the C++ one's library); what is removed is only their
# entry in the list of generators rosidl_generate_interfaces runs, whenever one is appended.
set(_ball_world_dropped_generators
  rosidl_generator_cpp
  rosidl_typesupport_cpp
  rosidl_typesupport_fastrtps_cpp
  rosidl_typesupport_introspection_cpp)

macro(_ball_world_drop_cpp_generators variable access)
  if("${access}" STREQUAL "MODIFIED_ACCESS")
    set(_ball_world_kept)
    foreach(_ball_world_extension IN LISTS ${variable})
      string(REGEX REPLACE ":.*" "" _ball_world_package "${_ball_world_extension}")
      if(NOT _ball_world_package IN_LIST _ball_world_dropped_generators)
        list(APPEND _ball_world_kept "${_ball_world_extension}")
      endif()
    endforeach()
    # Setting it again calls this once more, with nothing left to drop: no loop.
    if(NOT "${_ball_world_kept}" STREQUAL "${${variable}}")
      set(${variable} "${_ball_world_kept}")
    endif()
  endif()
endmacro()

variable_watch(AMENT_EXTENSIONS_rosidl_generate_idl_interfaces _ball_world_drop_cpp_generators)

# The typesupport libraries and the Python extension are compiled as unity builds (one source
# file per target, including all of its generated files): their files each include the same
# heavy headers (Fast CDR's C++ among them), and parsing those once per target instead of once
# per interface took the build of simulation_interfaces from 57 to 40 s of CPU (measured
# 2026-12-02). rosidl_generator_c's own files cannot be: each type's description file defines
# the same static names. Set once the package's CMakeLists.txt has made its targets.
function(_ball_world_unity_typesupports)
  get_property(_ball_world_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY BUILDSYSTEM_TARGETS)
  foreach(_ball_world_target IN LISTS _ball_world_targets)
    if(_ball_world_target MATCHES
       "__rosidl_(typesupport_fastrtps_c|typesupport_introspection_c|typesupport_c|generator_py)$")
      set_target_properties(${_ball_world_target} PROPERTIES
        UNITY_BUILD ON UNITY_BUILD_BATCH_SIZE 0)
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _ball_world_unity_typesupports)
