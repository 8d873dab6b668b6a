# The gRPC system of icars-compare (grpc/grpc_system.cc, make_grpc()): optional, built when
# Debian's libgrpc++-dev, libprotobuf-dev, protobuf-compiler and protobuf-compiler-grpc are
# installed. Defines the static library icars_compare_grpc, or nothing.
find_package(Protobuf QUIET)
find_package(gRPC CONFIG QUIET)
find_program(ICARS_GRPC_CPP_PLUGIN grpc_cpp_plugin)

if(Protobuf_FOUND AND Protobuf_PROTOC_EXECUTABLE AND TARGET gRPC::grpc++ AND ICARS_GRPC_CPP_PLUGIN)
  set(_icars_grpc_found ON)
else()
  set(_icars_grpc_found OFF)
endif()
option(ICARS_BENCH_WITH_GRPC "Compare gRPC in icars-compare" ${_icars_grpc_found})
set(_icars_grpc_needs "libgrpc++-dev, libprotobuf-dev, protobuf-compiler, protobuf-compiler-grpc")
if(NOT _icars_grpc_found)
  if(ICARS_BENCH_WITH_GRPC)
    message(WARNING "icars-compare: without gRPC, not found (needs ${_icars_grpc_needs})")
  else()
    message(STATUS "icars-compare: without gRPC, not found (needs ${_icars_grpc_needs})")
  endif()
  return()
endif()
if(NOT ICARS_BENCH_WITH_GRPC)
  message(STATUS "icars-compare: without gRPC (ICARS_BENCH_WITH_GRPC=OFF)")
  return()
endif()
message(STATUS "icars-compare: with gRPC ${gRPC_VERSION} (protobuf ${Protobuf_VERSION})")

set(_icars_grpc_proto ${CMAKE_CURRENT_LIST_DIR}/grpc/bench.proto)
set(_icars_grpc_gen ${CMAKE_CURRENT_BINARY_DIR}/grpc_gen)
set(_icars_grpc_sources
  ${_icars_grpc_gen}/bench.pb.cc ${_icars_grpc_gen}/bench.pb.h
  ${_icars_grpc_gen}/bench.grpc.pb.cc ${_icars_grpc_gen}/bench.grpc.pb.h)
add_custom_command(
  OUTPUT ${_icars_grpc_sources}
  COMMAND ${CMAKE_COMMAND} -E make_directory ${_icars_grpc_gen}
  COMMAND ${Protobuf_PROTOC_EXECUTABLE} --proto_path=${CMAKE_CURRENT_LIST_DIR}/grpc
          --cpp_out=${_icars_grpc_gen} --grpc_out=${_icars_grpc_gen}
          --plugin=protoc-gen-grpc=${ICARS_GRPC_CPP_PLUGIN} ${_icars_grpc_proto}
  DEPENDS ${_icars_grpc_proto} ${Protobuf_PROTOC_EXECUTABLE} ${ICARS_GRPC_CPP_PLUGIN}
  COMMENT "Generating the gRPC code of icars-compare from bench.proto"
  VERBATIM)

# Generated code is compiled without our warnings, and its headers are SYSTEM headers so that
# they do not trip the warnings of grpc_system.cc either.
add_library(icars_compare_grpc_proto OBJECT ${_icars_grpc_sources})
target_include_directories(icars_compare_grpc_proto SYSTEM PUBLIC ${_icars_grpc_gen})
target_link_libraries(icars_compare_grpc_proto PUBLIC gRPC::grpc++ protobuf::libprotobuf)

# Linking the object library directly puts its objects into this archive.
add_library(icars_compare_grpc STATIC ${CMAKE_CURRENT_LIST_DIR}/grpc/grpc_system.cc)
target_link_libraries(icars_compare_grpc
  PUBLIC gRPC::grpc++ protobuf::libprotobuf Threads::Threads
  PRIVATE icars_compare_grpc_proto icars_warnings)

unset(_icars_grpc_found)
unset(_icars_grpc_needs)
unset(_icars_grpc_proto)
unset(_icars_grpc_gen)
unset(_icars_grpc_sources)
