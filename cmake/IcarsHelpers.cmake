# icars_add_test(NAME <name> SOURCES <files...> LIBS <targets...> [TIMEOUT <s>]
#                [LABELS <labels...>] [ENVIRONMENT <VAR=value...>] [SERIAL])
# One GoogleTest executable per feature, registered with CTest test by test.
function(icars_add_test)
  cmake_parse_arguments(T "SERIAL" "NAME;TIMEOUT" "SOURCES;LIBS;LABELS;ENVIRONMENT" ${ARGN})
  if(NOT ICARS_BUILD_TESTS)
    return()
  endif()
  add_executable(${T_NAME} ${T_SOURCES})
  target_link_libraries(${T_NAME} PRIVATE ${T_LIBS} GTest::gtest GTest::gtest_main icars_warnings)
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 120)
  endif()
  set(serial FALSE)
  if(T_SERIAL)
    set(serial TRUE)  # heavy tests (many processes, 100 MB) run alone, so they stay meaningful
  endif()
  gtest_discover_tests(${T_NAME} DISCOVERY_TIMEOUT 60
    PROPERTIES TIMEOUT ${T_TIMEOUT} LABELS "${T_LABELS}" ENVIRONMENT "${T_ENVIRONMENT}"
               RUN_SERIAL ${serial})
endfunction()
