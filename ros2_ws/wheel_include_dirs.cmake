# The ROS 2 PyPI wheels export CMake targets whose INTERFACE_INCLUDE_DIRECTORIES name the
# Python and NumPy headers of the machine that built them (/opt/python/cp311-cp311/...).
# Replace those directories with this interpreter's headers (otherwise the generate step
# fails with "includes non-existent path" as soon as a message uses a type of another
# package, e.g. builtin_interfaces/Time). Include directories of imported targets are read
# at generate time, so including this after rosidl_generate_interfaces, which imported
# everything, covers every target. Needs find_package(Python3 ... Development NumPy) first.
get_property(_formic_imported DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(_target IN LISTS _formic_imported)
  get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
  if(NOT _dirs)
    continue()
  endif()
  set(_fixed)
  set(_changed FALSE)
  foreach(_dir IN LISTS _dirs)
    if(_dir MATCHES "^/opt/python/")
      set(_changed TRUE)
      if(_dir MATCHES "numpy")
        list(APPEND _fixed ${Python3_NumPy_INCLUDE_DIRS})
      else()
        list(APPEND _fixed ${Python3_INCLUDE_DIRS})
      endif()
    else()
      list(APPEND _fixed "${_dir}")
    endif()
  endforeach()
  if(_changed)
    list(REMOVE_DUPLICATES _fixed)
    set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_fixed}")
  endif()
endforeach()
