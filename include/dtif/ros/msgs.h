// The package's generated messages and services, in C++ namespace `dtif_msgs`.
//
// gencpp puts them in namespace `dtif` (the package name), where the core already declares
// dtif::Trunk and dtif::LoopClosure: the two cannot meet in one translation unit. The glue
// therefore includes the generated headers only through this file, which renames their
// namespace. Wire format, type names ("dtif/LoopClosure") and MD5 sums are unchanged (string
// literals are not macro-expanded). Every glue file and glue test must include this header
// instead of <dtif/*.h> message headers.
#pragma once

// Everything the generated headers include, first, so the rename touches only dtif's own types.
#include <geometry_msgs/Pose.h>
#include <ros/builtin_message_traits.h>
#include <ros/message_operations.h>
#include <ros/serialization.h>
#include <ros/service_traits.h>
#include <ros/types.h>
#include <std_msgs/Header.h>

#ifdef dtif
#error "dtif/ros/msgs.h: the macro dtif is already defined"
#endif
#define dtif dtif_msgs
#include <dtif/GetDatabaseSize.h>
#include <dtif/LoadDatabase.h>
#include <dtif/LoopClosure.h>
#include <dtif/SaveDatabase.h>
#include <dtif/Trunk.h>
#include <dtif/TrunkDescriptor.h>
#undef dtif
