"""Defaults shared by several layers, in one place (light to import: the CLI reads them for --help)."""

#: contact penalty stiffness, N/mm^3: contact pressure (MPa) per mm of penetration, area-weighted
#: (facesim.contact.penalty, facesim.contact.self_contact, the contact set-up of fem.equilibrium)
CONTACT_STIFFNESS = 1.0
