#include <gtest/gtest.h>
TEST(CmgenCrosscheck, Placeholder) {}
