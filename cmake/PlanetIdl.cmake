# planet_idl_generate(TARGET <target> FILES <idl files...>
#                     [OUTPUT_DIR <dir>] [IMPORT_DIRS <dirs...>])
#
# Compiles PLANET IDL files (docs/idl.md) with planet-idl into <stem>.planet.h/.planet.cc in
# OUTPUT_DIR (default: <current binary dir>/planet_idl/<target>), adds the generated sources to
# <target>, and OUTPUT_DIR to its PUBLIC include directories. <target> must link icars::planet.
# The files are regenerated when an IDL file, a file it includes or the compiler changes.
#
# The compiler is $<TARGET_FILE:icars::planet-idl> (built in this project, or imported by
# find_package(ICARS)); set PLANET_IDL_EXECUTABLE to use another one.
include_guard(GLOBAL)

function(planet_idl_generate)
  cmake_parse_arguments(PARSE_ARGV 0 IDL "" "TARGET;OUTPUT_DIR" "FILES;IMPORT_DIRS")
  if(NOT IDL_TARGET OR NOT IDL_FILES)
    message(FATAL_ERROR "planet_idl_generate: TARGET and FILES are required")
  endif()
  if(IDL_UNPARSED_ARGUMENTS)
    message(FATAL_ERROR "planet_idl_generate: unknown arguments: ${IDL_UNPARSED_ARGUMENTS}")
  endif()
  if(NOT IDL_OUTPUT_DIR)
    set(IDL_OUTPUT_DIR "${CMAKE_CURRENT_BINARY_DIR}/planet_idl/${IDL_TARGET}")
  endif()
  get_filename_component(IDL_OUTPUT_DIR "${IDL_OUTPUT_DIR}" ABSOLUTE
                         BASE_DIR "${CMAKE_CURRENT_BINARY_DIR}")

  if(PLANET_IDL_EXECUTABLE)
    set(compiler "${PLANET_IDL_EXECUTABLE}")
    set(compiler_depends "${PLANET_IDL_EXECUTABLE}")
  elseif(TARGET icars::planet-idl)
    # An ALIAS cannot be named in DEPENDS; the target it stands for (or the imported one) can.
    get_target_property(tool icars::planet-idl ALIASED_TARGET)
    if(NOT tool)
      set(tool icars::planet-idl)
    endif()
    set(compiler "$<TARGET_FILE:${tool}>")
    set(compiler_depends ${tool} "$<TARGET_FILE:${tool}>")
  else()
    message(FATAL_ERROR "planet_idl_generate: no target icars::planet-idl and no "
                        "PLANET_IDL_EXECUTABLE; find_package(ICARS) or set the variable")
  endif()

  set(import_args "")
  foreach(dir IN LISTS IDL_IMPORT_DIRS)
    get_filename_component(dir "${dir}" ABSOLUTE)
    list(APPEND import_args -I "${dir}")
  endforeach()

  set(generated_sources "")
  foreach(file IN LISTS IDL_FILES)
    get_filename_component(file "${file}" ABSOLUTE)
    get_filename_component(stem "${file}" NAME_WE)
    set(header "${IDL_OUTPUT_DIR}/${stem}.planet.h")
    set(source "${IDL_OUTPUT_DIR}/${stem}.planet.cc")
    set(depfile "${IDL_OUTPUT_DIR}/${stem}.planet.d")
    add_custom_command(
      OUTPUT "${header}" "${source}"
      COMMAND ${compiler} ${import_args} --output-dir "${IDL_OUTPUT_DIR}"
              --depfile "${depfile}" "${file}"
      DEPENDS "${file}" ${compiler_depends}
      DEPFILE "${depfile}"
      COMMENT "planet-idl: generating C++ from ${stem}.idl"
      VERBATIM)
    list(APPEND generated_sources "${header}" "${source}")
  endforeach()

  target_sources(${IDL_TARGET} PRIVATE ${generated_sources})
  target_include_directories(${IDL_TARGET} PUBLIC "$<BUILD_INTERFACE:${IDL_OUTPUT_DIR}>")
endfunction()
