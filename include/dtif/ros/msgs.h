// The package's generated messages and services (namespace dtif, beside the core's types:
// the core names its own types TrunkLandmark and Loop so that the two never clash).
#pragma once

#include <dtif/GetDatabaseSize.h>
#include <dtif/GetMapInfo.h>
#include <dtif/InventoryStem.h>
#include <dtif/LoadDatabase.h>
#include <dtif/LoopClosure.h>
#include <dtif/SaveDatabase.h>
#include <dtif/SaveMap.h>
#include <dtif/StemInventory.h>
#include <dtif/Trunk.h>
#include <dtif/TrunkDescriptor.h>
