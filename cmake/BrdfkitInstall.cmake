include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

# Headers under include/brdfkit/<folder>, as the sources include them
# ("brdf/model.h", "fit/fit.h").
foreach(dir brdf validate data_synth fit formats)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/${dir}/
          DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/brdfkit/${dir}
          FILES_MATCHING PATTERN "*.h")
endforeach()
# Two export sets: brdfkit::brdf needs Eigen alone; the compiled libraries
# need Ceres, TBB, OpenEXR and nlohmann-json, which brdfkitConfig.cmake looks
# for only when a compiled component is asked for.
install(TARGETS brdfkit_brdf EXPORT brdfkitTargets)
install(EXPORT brdfkitTargets
        NAMESPACE brdfkit::
        DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/brdfkit)
install(TARGETS brdfkit_validate brdfkit_synth brdfkit_fit brdfkit_formats EXPORT brdfkitLibraryTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR})
install(EXPORT brdfkitLibraryTargets
        NAMESPACE brdfkit::
        DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/brdfkit)
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/brdfkitConfig.cmake.in
        ${PROJECT_BINARY_DIR}/brdfkitConfig.cmake
        INSTALL_DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/brdfkit)
write_basic_package_version_file(${PROJECT_BINARY_DIR}/brdfkitConfigVersion.cmake
        COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/brdfkitConfig.cmake ${PROJECT_BINARY_DIR}/brdfkitConfigVersion.cmake
        DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/brdfkit)
install(TARGETS brdfkit RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
