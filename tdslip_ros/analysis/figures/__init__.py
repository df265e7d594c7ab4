"""The paper's figures 4-13 from the model core, one module per family: open loop (figs 4-6,
:mod:`.open_loop`), the exact plant's basins (figs 7 and 10, :mod:`.exact_basins`), energy regulation
(figs 8, 9 and the stable ranges, :mod:`.regulated`), parameter dependence (fig 11,
:mod:`.parameter_dependence`), ground reaction forces and virtual footfalls (fig 12, :mod:`.ground_reaction`)
and deadbeat against ref. 36's stance PD (fig 13, :mod:`.tracking`); :mod:`.common` holds what they share,
:mod:`.shared` the registry of the computations several make, :mod:`.catalogue` the figures by name."""
