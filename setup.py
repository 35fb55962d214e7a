"""Maps the repository's top-level folders onto the ``graytrack`` import namespace.

The design keeps ``core/``, ``drivers/``, ``service/`` and ``web/`` as top-level folders while the
installed names are ``graytrack.core`` and so on; setuptools' ``package_dir`` does that mapping for
regular and editable installs alike. Subpackages are discovered so nobody has to list them here.
"""

from setuptools import find_packages, setup

FOLDER_OF_PACKAGE = {
    "graytrack": "graytrack",
    "graytrack.core": "core",
    "graytrack.drivers": "drivers",
    "graytrack.service": "service",
    "graytrack.web": "web",
}

packages: list[str] = []
for package, folder in FOLDER_OF_PACKAGE.items():
    packages.append(package)
    packages.extend(f"{package}.{sub}" for sub in find_packages(folder))

setup(
    packages=packages,
    package_dir=FOLDER_OF_PACKAGE,
    package_data={"graytrack.web": ["*.html", "*.js", "*.css", "*.svg", "static/*"]},
    include_package_data=False,
)
