# Included at the end of a rosidl package's CMakeLists.txt (after its find_package calls).
#
# The ROS 2 PyPI wheels export CMake targets (<pkg>::<pkg>__rosidl_generator_py) whose include
# directories are the wheel builder's paths (/opt/python/cp311-cp311/include/python3.11 and its
# numpy include dir). CMake refuses imported targets with missing include directories, so
# point every missing Python/NumPy include dir of an imported target at this interpreter's.
# Nothing changes when the paths exist (a regular ROS install).
get_directory_property(_imported_targets IMPORTED_TARGETS)
foreach(_target IN LISTS _imported_targets)
  get_target_property(_incs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
  if(NOT _incs)
    continue()
  endif()
  set(_fixed "")
  set(_changed FALSE)
  foreach(_inc IN LISTS _incs)
    if(NOT _inc MATCHES "^\\$<" AND NOT EXISTS "${_inc}")
      if(_inc MATCHES "numpy")
        list(APPEND _fixed ${Python3_NumPy_INCLUDE_DIRS})
        set(_changed TRUE)
        continue()
      elseif(_inc MATCHES "include/python3")
        list(APPEND _fixed ${Python3_INCLUDE_DIRS})
        set(_changed TRUE)
        continue()
      endif()
    endif()
    list(APPEND _fixed "${_inc}")
  endforeach()
  if(_changed)
    list(REMOVE_DUPLICATES _fixed)
    set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_fixed}")
    message(STATUS "${PROJECT_NAME}: fixed wheel-builder include paths of ${_target}")
  endif()
endforeach()
