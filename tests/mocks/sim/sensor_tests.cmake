# Tests of the simulated camera's sensor model (mocks/sim/sensor*.{h,cpp}).
commonlight_test(sim sensor SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/sensor_test.cpp DEPS commonlight::sim)
commonlight_test(sim sensor_params SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/sensor_params_test.cpp DEPS commonlight::sim)
