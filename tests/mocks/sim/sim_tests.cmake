commonlight_test(sim trajectory SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/trajectory_test.cpp DEPS commonlight::sim)
