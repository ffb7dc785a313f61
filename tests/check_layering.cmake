# The house rule of the layout (README, "Layout"), checked on every include line. Each
# module (a folder) may include only the include prefixes (markcell/<prefix>/) below it:
#   common/   (checks, time, buffers, msg/ leaf messages, geometry): includes only itself
#   drivers/  common and itself            vision/  common and itself (and OpenCV)
#   control/  common, drivers and itself: never vision/, the host or OpenCV, so the
#             executive and the marking task cross-build for the cell's board alone
#   rig/sim/  (markcell/sim: the simulated world's pieces) common, drivers, control, itself
#   firmware_host/service/ (markcell/host) all of the above: never the rig or the tools,
#             so the cell knows nothing of the rig but its simulated world
#   rig/      (markcell/rig) the service and everything under it
#   firmware_host/tools/ (markcell/tools) everything but main.cpp
# Run as `cmake -DROOT=<source dir> -P check_layering.cmake`; fails naming each file:line.
set(modules common drivers vision control rig/sim firmware_host/service rig firmware_host/tools)
set(allowed_common "common|msg")
set(allowed_drivers "common|msg|drivers")
set(allowed_vision "common|msg|vision")
set(allowed_control "common|msg|drivers|control")
set(allowed_rig/sim "common|msg|drivers|control|sim")
set(allowed_firmware_host/service "common|msg|drivers|vision|control|sim|host")
set(allowed_rig "common|msg|drivers|vision|control|sim|host|rig")
set(allowed_firmware_host/tools "common|msg|drivers|vision|control|sim|host|rig|tools")
set(no_opencv common drivers control rig/sim)
set(problems "")
foreach(module ${modules})
  file(GLOB_RECURSE files "${ROOT}/${module}/*.hpp" "${ROOT}/${module}/*.cpp" "${ROOT}/${module}/*.h")
  if(module STREQUAL "rig")  # rig/sim is a module of its own, below the service
    list(FILTER files EXCLUDE REGEX "^${ROOT}/rig/sim/")
  endif()
  list(SORT files)
  list(FIND no_opencv ${module} no_opencv_at)
  foreach(f ${files})
    file(RELATIVE_PATH rel "${ROOT}" "${f}")
    # Line by line (STRINGS keeps empty lines as "" only with this regex), for file:line.
    file(STRINGS "${f}" lines REGEX "^.*$")
    set(n 0)
    foreach(line IN LISTS lines)
      math(EXPR n "${n} + 1")
      if(NOT line MATCHES "^[ \t]*#[ \t]*include")
        continue()
      endif()
      if(line MATCHES "[<\"]markcell/([a-z_]+)/" AND NOT CMAKE_MATCH_1 MATCHES "^(${allowed_${module}})$")
        list(APPEND problems "${rel}:${n}: ${line}  (${module}/ may include only ${allowed_${module}})")
      endif()
      if(no_opencv_at GREATER -1 AND line MATCHES "[<\"]opencv2/")
        list(APPEND problems "${rel}:${n}: ${line}  (${module}/ must build without OpenCV)")
      endif()
    endforeach()
  endforeach()
endforeach()
if(problems)
  list(JOIN problems "\n  " text)
  message(FATAL_ERROR "layering: includes across the layout's rule:\n  ${text}")
endif()
message(STATUS "layering: every include of ${modules} keeps the rule")
