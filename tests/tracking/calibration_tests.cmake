# Tests of tracking/calibration_board and tracking/calibration: board specs, detection, rejection,
# coverage and the YAML (synthetic corners), and calibration on images rendered by mocks/sim.
commonlight_test(tracking calibration_sim SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/calibration_sim_test.cpp
                 DEPS commonlight::tracking commonlight::sim TIMEOUT 600)
