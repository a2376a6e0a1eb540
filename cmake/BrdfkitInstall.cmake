include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

install(DIRECTORY ${PROJECT_SOURCE_DIR}/brdf/
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/brdfkit/brdf
        FILES_MATCHING PATTERN "*.h")
install(TARGETS brdfkit_brdf EXPORT brdfkitTargets)
install(EXPORT brdfkitTargets
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
