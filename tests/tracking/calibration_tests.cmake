# Tests of tracking/calibration_board and tracking/calibration: board specs and detection, the
# calibration on synthetic corners (rejection, coverage, errors, the YAML), and calibration on
# images rendered by mocks/sim (accuracy; about 15 s each in Release, 2-3 minutes under ASan on a busy machine).
commonlight_test(tracking calibration_board SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/calibration_board_test.cpp
                 DEPS commonlight::tracking)
commonlight_test(tracking calibration SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/calibration_test.cpp
                 DEPS commonlight::tracking)
foreach(board chessboard aprilgrid)
  commonlight_test(tracking calibration_sim_${board}
                   SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/calibration_sim_${board}_test.cpp
                           ${CMAKE_CURRENT_SOURCE_DIR}/calibration_sim_support.cpp
                   DEPS commonlight::tracking commonlight::sim TIMEOUT 600)
endforeach()
