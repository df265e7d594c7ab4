# The ROS 2 Kilted PyPI wheels were built under /opt/python/<abi>/ and their exported
# `<pkg>::<pkg>__rosidl_generator_py` targets carry that interpreter's include directories
# (Python headers and numpy headers) baked in. Those paths do not exist here, and CMake refuses
# to generate a build that links such a target. relocate_wheel_python_includes() rewrites every
# imported target of this directory whose include directory is missing and belongs to a Python
# installation: Python headers go to this build's Python3_INCLUDE_DIRS, numpy headers to
# Python3_NumPy_INCLUDE_DIRS. On a regular ROS 2 install all paths exist and nothing changes.
# Any other missing include directory is reported as a fatal error naming the target.

function(relocate_wheel_python_includes)
  # Same components rosidl_generator_py asks for; the cached result of its search is reused.
  find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
  get_property(_targets DIRECTORY PROPERTY IMPORTED_TARGETS)
  set(_relocated 0)
  foreach(_target IN LISTS _targets)
    get_target_property(_includes ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _includes)
      continue()
    endif()
    set(_fixed "")
    set(_changed FALSE)
    foreach(_dir IN LISTS _includes)
      if(IS_DIRECTORY "${_dir}" OR _dir MATCHES "^\\$<")
        list(APPEND _fixed "${_dir}")
      elseif(_dir MATCHES "/numpy/(_core/|core/)?include$")
        list(APPEND _fixed ${Python3_NumPy_INCLUDE_DIRS})
        set(_changed TRUE)
      elseif(_dir MATCHES "/include/python3\\.[0-9]+$")
        list(APPEND _fixed ${Python3_INCLUDE_DIRS})
        set(_changed TRUE)
      else()
        message(FATAL_ERROR "Imported target ${_target} has a missing include directory '${_dir}' "
          "that is neither a Python nor a numpy header directory")
      endif()
    endforeach()
    if(_changed)
      list(REMOVE_DUPLICATES _fixed)
      set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_fixed}")
      math(EXPR _relocated "${_relocated} + 1")
    endif()
  endforeach()
  if(_relocated GREATER 0)
    message(STATUS "Relocated the Python include directories of ${_relocated} imported targets "
      "to ${Python3_INCLUDE_DIRS};${Python3_NumPy_INCLUDE_DIRS}")
  endif()
endfunction()
