# With -DTWINSLAM_PYTHON_ONLY=ON (what `make` passes for the project's virtual environment, in
# which every node is a Python node) an interface package is generated for C and Python only:
# rclpy reaches a message through its C type support (rosidl_typesupport_c, Fast DDS' and the
# introspection's C type supports), never the C++ ones, which take most of a build's compile
# time (composition_interfaces: 11 s of CPU instead of 20 s, measured). A ROS 2 host's colcon
# build leaves the option off and gets every generator, C++ nodes included.
# Included after the generators were found, before rosidl_generate_interfaces().
option(TWINSLAM_PYTHON_ONLY "generate the C and Python interfaces only (no C++)" OFF)
if(TWINSLAM_PYTHON_ONLY)
  list(FILTER AMENT_EXTENSIONS_rosidl_generate_idl_interfaces EXCLUDE REGEX "_cpp:")
  message(STATUS "TWINSLAM_PYTHON_ONLY: generating ${AMENT_EXTENSIONS_rosidl_generate_idl_interfaces}")
endif()
