# For a message package that is not ours (run.sh builds ../shared/ros2-tools/src/* with it): passed as
# -DCMAKE_PROJECT_INCLUDE=, CMake reads it right after that package's project() call. It defers
# relocate_wheel_python_includes() to the end of the package's configure step, when every imported
# target exists, so that the package's own CMakeLists.txt stays as upstream wrote it.
include("${CMAKE_CURRENT_LIST_DIR}/relocate_wheel_python_includes.cmake")
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL relocate_wheel_python_includes)
