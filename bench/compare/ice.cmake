# ZeroC Ice 3.7 for icars-compare, C++11 mapping (Debian: libzeroc-ice-dev, zeroc-ice-compilers,
# zeroc-ice-slice). Defines icars_compare_ice when Ice is found; otherwise says so and does nothing.
# Debian's pkg-config "ice" is X11's Inter-Client Exchange library, hence the explicit look-ups.
find_program(ICARS_SLICE2CPP slice2cpp)
find_library(ICARS_ICE_LIBRARY NAMES Ice++11)
find_path(ICARS_ICE_INCLUDE_DIR Ice/Ice.h)
find_path(ICARS_ICE_SLICE_DIR Ice/BuiltinSequences.ice PATH_SUFFIXES ice/slice share/ice/slice)
mark_as_advanced(ICARS_SLICE2CPP ICARS_ICE_LIBRARY ICARS_ICE_INCLUDE_DIR ICARS_ICE_SLICE_DIR)

if(ICARS_SLICE2CPP AND ICARS_ICE_LIBRARY AND ICARS_ICE_INCLUDE_DIR AND ICARS_ICE_SLICE_DIR)
  set(_icars_ice_found ON)
else()
  set(_icars_ice_found OFF)
endif()
option(ICARS_BENCH_WITH_ICE "Build ZeroC Ice into icars-compare" ${_icars_ice_found})

if(NOT _icars_ice_found)
  message(STATUS "icars-compare: without ZeroC Ice (slice2cpp, libIce++11, Ice headers or Slice "
                 "files not found: Debian libzeroc-ice-dev zeroc-ice-compilers zeroc-ice-slice)")
elseif(NOT ICARS_BENCH_WITH_ICE)
  message(STATUS "icars-compare: without ZeroC Ice (ICARS_BENCH_WITH_ICE=OFF)")
else()
  message(STATUS "icars-compare: with ZeroC Ice (${ICARS_ICE_LIBRARY})")

  # Generated code goes to <build>/bench/compare/slice/compare_ice/Bench.{h,cpp}, included as
  # <compare_ice/Bench.h>.
  set(_icars_ice_gen_root ${CMAKE_CURRENT_BINARY_DIR}/slice)
  set(_icars_ice_gen_dir ${_icars_ice_gen_root}/compare_ice)
  add_custom_command(
    OUTPUT ${_icars_ice_gen_dir}/Bench.h ${_icars_ice_gen_dir}/Bench.cpp
    COMMAND ${CMAKE_COMMAND} -E make_directory ${_icars_ice_gen_dir}
    COMMAND ${ICARS_SLICE2CPP} -I${ICARS_ICE_SLICE_DIR} --include-dir compare_ice
            --output-dir ${_icars_ice_gen_dir} ${CMAKE_CURRENT_SOURCE_DIR}/ice/Bench.ice
    DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/ice/Bench.ice ${ICARS_SLICE2CPP}
    COMMENT "slice2cpp Bench.ice"
    VERBATIM)

  # Generated code: no project warnings; its headers (and Ice's) are SYSTEM for its users.
  add_library(icars_compare_ice_slice STATIC ${_icars_ice_gen_dir}/Bench.cpp)
  target_include_directories(icars_compare_ice_slice SYSTEM PUBLIC
    ${_icars_ice_gen_root} ${ICARS_ICE_INCLUDE_DIR})
  target_compile_definitions(icars_compare_ice_slice PUBLIC ICE_CPP11_MAPPING)
  target_link_libraries(icars_compare_ice_slice PUBLIC ${ICARS_ICE_LIBRARY} Threads::Threads)

  add_library(icars_compare_ice STATIC ${CMAKE_CURRENT_SOURCE_DIR}/ice/ice_system.cc)
  target_include_directories(icars_compare_ice PRIVATE ${CMAKE_CURRENT_SOURCE_DIR})
  target_link_libraries(icars_compare_ice PRIVATE icars_compare_ice_slice icars_warnings)
endif()
