# Installs an ICARS build into a scratch prefix, then builds each downstream project against it
# with find_package(ICARS) and runs it, as a downstream user would:
#   examples/idl_project     a device provider's program (planet_idl_generate, icars::planet)
#   examples/plugin_project  a plugin, run by the installed `icars` (WITH_HOME only)
#
# cmake -DBUILD_DIR=... -DSOURCE_DIR=... -DWORK_DIR=... -DGENERATOR=... -DBUILD_TYPE=...
#       -DCXX_FLAGS=... -DWITH_HOME=ON|OFF -P check_installed.cmake
function(run what expected)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  message("${out}")
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${what} failed (${rc}):\n${out}\n${err}")
  endif()
  foreach(line IN LISTS expected)
    string(FIND "${out}" "${line}" at)
    if(at EQUAL -1)
      message(FATAL_ERROR "${what}: the output lacks '${line}'")
    endif()
  endforeach()
endfunction()

# Configures and builds the downstream project `name` of examples/.
function(build name)
  run("configuring ${name}" "" ${CMAKE_COMMAND} -S "${SOURCE_DIR}/examples/${name}" -B "${WORK_DIR}/${name}"
      -G "${GENERATOR}" "-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix" "-DCMAKE_BUILD_TYPE=${BUILD_TYPE}"
      "-DCMAKE_CXX_FLAGS=${CXX_FLAGS}")
  run("building ${name}" "" ${CMAKE_COMMAND} --build "${WORK_DIR}/${name}")
endfunction()

file(REMOVE_RECURSE "${WORK_DIR}")
run("installing ICARS" "" ${CMAKE_COMMAND} --install "${BUILD_DIR}" --prefix "${WORK_DIR}/prefix")

build(idl_project)
run("running idl_project" "example ok" "${WORK_DIR}/idl_project/home_devices")

if(WITH_HOME)
  build(plugin_project)
  set(project "${SOURCE_DIR}/examples/plugin_project")
  run("running the installed icars with the plugin"
      "living_light: intensity 30;Dimming -> Resting on done"
      "${WORK_DIR}/prefix/bin/icars" run "${project}/evening.xml" --world "${project}/flat.xml"
      --plugin "${WORK_DIR}/plugin_project/evening_lights.so" --until 18:30 --speed 3000)
  run("listing the plugin's behavior types" "DimLights: sets every light of a room"
      "${WORK_DIR}/prefix/bin/icars" behaviors --plugin "${WORK_DIR}/plugin_project/evening_lights.so")
endif()
message("downstream projects ok")
