# The PyPI wheels of ROS 2 Jazzy export include directories of the machine that built them
# (/opt/python/cp311-cp311/include/python3.11, the manylinux interpreter) on their
# *__rosidl_generator_py targets. CMake refuses to generate with an imported target naming a
# directory that does not exist, so drop such entries; this interpreter's own headers come in
# through Python3::Module. On a ROS host every listed directory exists and nothing changes.
# Included after rosidl_generate_interfaces() by every interface package the project builds.
get_property(_imported DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(_target IN LISTS _imported)
  get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
  if(NOT _dirs)
    continue()
  endif()
  set(_kept "")
  foreach(_dir IN LISTS _dirs)
    if(_dir MATCHES "^\\$<" OR EXISTS "${_dir}")
      list(APPEND _kept "${_dir}")
    else()
      message(STATUS "${_target}: ignoring the missing include directory ${_dir}")
    endif()
  endforeach()
  set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kept}")
endforeach()
