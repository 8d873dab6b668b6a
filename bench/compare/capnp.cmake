# Cap'n Proto RPC for icars-compare (capnp/capnp_system.cc, make_capnp()); Debian: libcapnp-dev and
# capnproto. Defines icars_compare_capnp when Cap'n Proto is found; otherwise says so and does
# nothing. Found through pkg-config, not CapnProtoConfig.cmake: Debian's 0.9 config checks for
# libatomic with a probe that fails in a C++-only project such as this one, and fails the whole
# configure (capnproto/capnproto#1448).
find_package(PkgConfig QUIET)
if(PKG_CONFIG_FOUND)
  pkg_check_modules(ICARS_CAPNP QUIET IMPORTED_TARGET capnp-rpc)
endif()
find_program(ICARS_CAPNP_EXECUTABLE capnp)
find_program(ICARS_CAPNPC_CXX_EXECUTABLE capnpc-c++)
mark_as_advanced(ICARS_CAPNP_EXECUTABLE ICARS_CAPNPC_CXX_EXECUTABLE)

if(ICARS_CAPNP_FOUND AND ICARS_CAPNP_EXECUTABLE AND ICARS_CAPNPC_CXX_EXECUTABLE)
  set(_icars_capnp_found ON)
else()
  set(_icars_capnp_found OFF)
endif()
option(ICARS_BENCH_WITH_CAPNP "Build Cap'n Proto RPC into icars-compare" ${_icars_capnp_found})

if(NOT _icars_capnp_found)
  message(STATUS "icars-compare: without Cap'n Proto (pkg-config's capnp-rpc, capnp or capnpc-c++ "
                 "not found: Debian libcapnp-dev capnproto)")
elseif(NOT ICARS_BENCH_WITH_CAPNP)
  message(STATUS "icars-compare: without Cap'n Proto (ICARS_BENCH_WITH_CAPNP=OFF)")
else()
  message(STATUS "icars-compare: with Cap'n Proto ${ICARS_CAPNP_VERSION}")

  # Generated code goes to <build>/bench/compare/capnp_gen/compare_capnp/bench.capnp.{h,c++},
  # included as <compare_capnp/bench.capnp.h>.
  set(_icars_capnp_schema ${CMAKE_CURRENT_SOURCE_DIR}/capnp/bench.capnp)
  set(_icars_capnp_gen_root ${CMAKE_CURRENT_BINARY_DIR}/capnp_gen)
  set(_icars_capnp_gen_dir ${_icars_capnp_gen_root}/compare_capnp)
  add_custom_command(
    OUTPUT ${_icars_capnp_gen_dir}/bench.capnp.h ${_icars_capnp_gen_dir}/bench.capnp.c++
    COMMAND ${CMAKE_COMMAND} -E make_directory ${_icars_capnp_gen_dir}
    COMMAND ${ICARS_CAPNP_EXECUTABLE} compile
            -o${ICARS_CAPNPC_CXX_EXECUTABLE}:${_icars_capnp_gen_dir} --src-prefix=${CMAKE_CURRENT_SOURCE_DIR}/capnp -I${ICARS_CAPNP_INCLUDEDIR}
            ${_icars_capnp_schema}
    DEPENDS ${_icars_capnp_schema} ${ICARS_CAPNP_EXECUTABLE} ${ICARS_CAPNPC_CXX_EXECUTABLE}
    COMMENT "capnp compile -oc++ bench.capnp"
    VERBATIM)

  # Generated code: no project warnings; its headers (and Cap'n Proto's) are SYSTEM for its users.
  add_library(icars_compare_capnp_schema STATIC ${_icars_capnp_gen_dir}/bench.capnp.c++)
  target_include_directories(icars_compare_capnp_schema SYSTEM PUBLIC ${_icars_capnp_gen_root})
  target_link_libraries(icars_compare_capnp_schema PUBLIC PkgConfig::ICARS_CAPNP)

  add_library(icars_compare_capnp STATIC ${CMAKE_CURRENT_SOURCE_DIR}/capnp/capnp_system.cc)
  target_include_directories(icars_compare_capnp PRIVATE ${CMAKE_CURRENT_SOURCE_DIR})
  target_link_libraries(icars_compare_capnp
    PRIVATE icars_compare_capnp_schema Threads::Threads icars_warnings)

  unset(_icars_capnp_schema)
  unset(_icars_capnp_gen_root)
  unset(_icars_capnp_gen_dir)
endif()
unset(_icars_capnp_found)
