// The test-only model's registration: this line is all it takes.
#include "fit/register_model.h"
#include "tests/test_glossy_model.h"

BRDFKIT_REGISTER_MODEL(brdfkit::test::TestGlossy);
