# Helpers shared by every module: one function makes a module library, one registers tests.

# Compile options applied to every target of the project.
add_library(commonlight_options INTERFACE)
target_compile_options(commonlight_options INTERFACE -Wall -Wextra -Wpedantic -Wshadow
                       -Wnon-virtual-dtor -Wcast-align -Woverloaded-virtual)
if(COMMONLIGHT_WERROR)
  target_compile_options(commonlight_options INTERFACE -Werror)
endif()
if(COMMONLIGHT_ASAN AND COMMONLIGHT_TSAN)
  message(FATAL_ERROR "COMMONLIGHT_ASAN and COMMONLIGHT_TSAN cannot be combined")
endif()
if(COMMONLIGHT_ASAN)
  target_compile_options(commonlight_options INTERFACE -fsanitize=address,undefined
                         -fno-sanitize-recover=undefined -fno-omit-frame-pointer)
  target_link_options(commonlight_options INTERFACE -fsanitize=address,undefined)
endif()
if(COMMONLIGHT_FUZZ)
  if(COMMONLIGHT_ASAN OR COMMONLIGHT_TSAN)
    message(FATAL_ERROR "COMMONLIGHT_FUZZ brings its own sanitizers: leave COMMONLIGHT_ASAN and COMMONLIGHT_TSAN off")
  endif()
  if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang" OR CMAKE_CXX_COMPILER_VERSION VERSION_LESS 16)
    message(FATAL_ERROR "COMMONLIGHT_FUZZ needs clang 16 or newer (CMAKE_CXX_COMPILER=clang++-16; scripts/fuzz sets it up), "
                        "found ${CMAKE_CXX_COMPILER_ID} ${CMAKE_CXX_COMPILER_VERSION}")
  endif()
  # Every object of a fuzz tree (core too) carries libFuzzer's coverage, ASan and UBSan; the
  # harness executables add -fsanitize=fuzzer (its main). libstdc++ 12 declares std::expected
  # (core/result.h) only when __cpp_concepts >= 202002, which clang 16 does not announce although
  # it implements what the header needs: say so (the macro is the compiler's, hence the warning
  # switched off). COMMONLIGHT_FUZZ_STRICT_READERS: an exception reaching a reader's border
  # aborts (core/reader_guard.h), so the fuzzer finds where a reader leaned on that net.
  add_compile_options(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined
                      -fno-omit-frame-pointer -g -D__cpp_concepts=202002L -Wno-macro-redefined
                      -DCOMMONLIGHT_FUZZ_STRICT_READERS)
  add_link_options(-fsanitize=address,undefined)
endif()
if(COMMONLIGHT_TSAN)
  target_compile_options(commonlight_options INTERFACE -fsanitize=thread -fno-omit-frame-pointer)
  target_link_options(commonlight_options INTERFACE -fsanitize=thread)
endif()

# commonlight_module(<name> [SOURCES ...] [DEPS ...] [PRIVATE_DEPS ...])
# Makes the library target commonlight_<name> with the alias commonlight::<name>. Without
# SOURCES, every .cpp directly in the module folder is compiled (CONFIGURE_DEPENDS glob).
# A module without sources is an INTERFACE target, so later issues can fill it in.
function(commonlight_module name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;PRIVATE_DEPS" ${ARGN})
  if(NOT ARG_SOURCES)
    file(GLOB ARG_SOURCES CONFIGURE_DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/*.cpp)
  endif()
  set(target commonlight_${name})
  if(ARG_SOURCES)
    add_library(${target} STATIC ${ARG_SOURCES})
    target_include_directories(${target} PUBLIC ${PROJECT_SOURCE_DIR})
    target_link_libraries(${target} PUBLIC ${ARG_DEPS} PRIVATE commonlight_options ${ARG_PRIVATE_DEPS})
  else()
    add_library(${target} INTERFACE)
    target_include_directories(${target} INTERFACE ${PROJECT_SOURCE_DIR})
    target_link_libraries(${target} INTERFACE ${ARG_DEPS})
  endif()
  add_library(commonlight::${name} ALIAS ${target})
endfunction()

# commonlight_sources(<module> <sources...>): adds sources (a backend folder, say) to a module.
function(commonlight_sources name)
  target_sources(commonlight_${name} PRIVATE ${ARGN})
endfunction()

# Environment of every test: where the sources and binaries are, and the sanitizer settings
# (TSan reads the project's suppressions of third-party false alarms from tests/tsan.supp).
set(COMMONLIGHT_TEST_ENV "COMMONLIGHT_SOURCE_DIR=${PROJECT_SOURCE_DIR}" "COMMONLIGHT_BINARY_DIR=${PROJECT_BINARY_DIR}")
if(COMMONLIGHT_TSAN)
  list(APPEND COMMONLIGHT_TEST_ENV
       "TSAN_OPTIONS=halt_on_error=1 second_deadlock_stack=1 suppressions=${PROJECT_SOURCE_DIR}/tests/tsan.supp")
endif()
# intercept_tls_get_addr=0: GCC 12's LeakSanitizer guesses the layout of a dynamic TLS block from
# its address and sometimes takes glibc 2.36's for glibc 2.19's; it then scans a nonsense range (seen
# as "DTLS 44 at 0x622e-0x1800007330" for Mesa's dlopened driver) and its tracer dies with SIGSEGV at
# exit, failing a quarter of `play --sync` runs (google/sanitizers#1322). Leaks are still checked;
# only pointers held in dlopened libraries' thread-local storage are no longer roots.
if(COMMONLIGHT_ASAN)
  list(APPEND COMMONLIGHT_TEST_ENV "ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:intercept_tls_get_addr=0"
       "UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1")
endif()

# A test's TIMEOUT guards against hangs. Under a sanitizer a test runs several times slower, and
# more so on a loaded machine (ci-run6: lighting/influence and e2e/sim_scenes, about 200 s under
# ASan on a quiet machine, passed 300 s at load 4-6): the sanitizer builds give three times as long.
set(COMMONLIGHT_TEST_TIMEOUT_SCALE 1)
if(COMMONLIGHT_ASAN OR COMMONLIGHT_TSAN)
  set(COMMONLIGHT_TEST_TIMEOUT_SCALE 3)
endif()

# commonlight_test(<module> <name> SOURCES ... [DEPS ...] [LABELS ...] [TIMEOUT s])
# A GoogleTest executable registered with CTest as "<module>/<name>". Exit code 77 means
# "skipped" (hardware, display or namespace not available).
function(commonlight_test module name)
  cmake_parse_arguments(ARG "" "TIMEOUT" "SOURCES;DEPS;LABELS" ${ARGN})
  set(target test_${module}_${name})
  add_executable(${target} ${ARG_SOURCES})
  target_link_libraries(${target} PRIVATE commonlight_options ${ARG_DEPS} GTest::gtest GTest::gmock
                        commonlight_test_main)
  add_test(NAME ${module}/${name} COMMAND ${target})
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 300)
  endif()
  math(EXPR ARG_TIMEOUT "${ARG_TIMEOUT} * ${COMMONLIGHT_TEST_TIMEOUT_SCALE}")
  set_tests_properties(${module}/${name} PROPERTIES SKIP_RETURN_CODE 77 TIMEOUT ${ARG_TIMEOUT}
                       LABELS "${module};${ARG_LABELS}" ENVIRONMENT "${COMMONLIGHT_TEST_ENV}")
endfunction()

# commonlight_script_test(<module> <name> COMMAND ... [LABELS ...] [TIMEOUT s])
# A test written as a script (end-to-end tests of the command line), registered like above.
function(commonlight_script_test module name)
  cmake_parse_arguments(ARG "" "TIMEOUT" "COMMAND;LABELS" ${ARGN})
  add_test(NAME ${module}/${name} COMMAND ${ARG_COMMAND})
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 300)
  endif()
  math(EXPR ARG_TIMEOUT "${ARG_TIMEOUT} * ${COMMONLIGHT_TEST_TIMEOUT_SCALE}")
  set_tests_properties(${module}/${name} PROPERTIES SKIP_RETURN_CODE 77 TIMEOUT ${ARG_TIMEOUT}
                       LABELS "${module};${ARG_LABELS}"
                       ENVIRONMENT "${COMMONLIGHT_TEST_ENV};COMMONLIGHT=$<TARGET_FILE:commonlight>")
endfunction()
