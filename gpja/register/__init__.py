"""Registration: HRA losses, the LargeSteps parameterisation, remeshing and the optimisation loop."""
