# icars_add_test(NAME <name> SOURCES <files...> LIBS <targets...> [TIMEOUT <s>]
#                [LABELS <label>] [ENVIRONMENT <VAR=value...>] [HEAVY])
# One GoogleTest executable per feature, registered with CTest test by test. HEAVY tests (many
# processes, a simulated week, 100 MB transfers) run one at a time; light tests run beside them.
function(icars_add_test)
  cmake_parse_arguments(T "HEAVY" "NAME;TIMEOUT;LABELS" "SOURCES;LIBS;ENVIRONMENT" ${ARGN})
  if(NOT ICARS_BUILD_TESTS)
    return()
  endif()
  add_executable(${T_NAME} ${T_SOURCES})
  target_link_libraries(${T_NAME} PRIVATE ${T_LIBS} GTest::gtest GTest::gtest_main icars_warnings)
  # A test's own code is glue around the libraries it drives: in a sanitizer (Debug) build it is
  # compiled unoptimised, which halves its compile time; the libraries keep the preset's -O1.
  target_compile_options(${T_NAME} PRIVATE $<$<CONFIG:Debug>:-O0>)
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 120)
  endif()
  set(properties TIMEOUT ${T_TIMEOUT})
  # A test has one label: gtest_discover_tests cannot pass a list through. ICARS_TEST_LABEL is
  # the label of every test of a directory (`home` under src/home, ...); a test's own LABELS are
  # joined to it with '-' ("home-soak"), so that `ctest -L home` and `ctest -L soak` both find it.
  set(labels ${ICARS_TEST_LABEL} ${T_LABELS})
  list(JOIN labels "-" label)
  if(label)
    list(APPEND properties LABELS "${label}")
  endif()
  if(T_ENVIRONMENT)
    list(APPEND properties ENVIRONMENT "${T_ENVIRONMENT}")
  endif()
  if(T_HEAVY)
    # One at a time, and first on a fresh tree (no cost data yet), so that light tests run
    # beside them instead of the heavy ones running alone at the end.
    list(APPEND properties RESOURCE_LOCK icars_heavy_test COST 1000)
  endif()
  gtest_discover_tests(${T_NAME} DISCOVERY_TIMEOUT 60 PROPERTIES ${properties})
endfunction()

# icars_add_library(<layer> <sources...>)
# One library per layer: target icars_<layer>, alias icars::<layer>, public headers in include/.
function(icars_add_library layer)
  add_library(icars_${layer} ${ARGN})
  add_library(icars::${layer} ALIAS icars_${layer})
  target_include_directories(icars_${layer} PUBLIC
    $<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}/include>
    $<INSTALL_INTERFACE:include>)
endfunction()

# icars_install_generated_idl(<target> <idl stems...>)
# Installs the headers planet_idl_generate() made for <target> from <stem>.idl into
# include/icars/planet_idl, where the installed <target> finds them.
function(icars_install_generated_idl target)
  foreach(stem IN LISTS ARGN)
    install(FILES ${CMAKE_CURRENT_BINARY_DIR}/planet_idl/${target}/${stem}.planet.h
      DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/icars/planet_idl)
  endforeach()
  target_include_directories(${target} PUBLIC
    $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}/icars/planet_idl>)
endfunction()

include(${CMAKE_CURRENT_LIST_DIR}/IcarsPlugin.cmake)
