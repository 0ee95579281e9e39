#include "dicom_writer.h"

#include <gdcmAttribute.h>
#include <gdcmDataSet.h>
#include <gdcmFileMetaInformation.h>
#include <gdcmImageWriter.h>
#include <gdcmMediaStorage.h>
#include <gdcmReader.h>
#include <gdcmSequenceOfItems.h>
#include <gdcmStringFilter.h>
#include <gdcmTrace.h>
#include <gdcmWriter.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <stdexcept>

namespace hyb::test {

namespace {

// A string element of value representation @p vr, padded to even length as DICOM requires.
gdcm::DataElement text(uint16_t group, uint16_t element, gdcm::VR vr, std::string value) {
  if (value.size() % 2) value += vr == gdcm::VR::UI ? '\0' : ' ';
  gdcm::DataElement de(gdcm::Tag(group, element));
  de.SetVR(vr);
  de.SetByteValue(value.data(), uint32_t(value.size()));
  return de;
}

gdcm::DataElement us(uint16_t group, uint16_t element, uint16_t v) {
  gdcm::DataElement de(gdcm::Tag(group, element));
  de.SetVR(gdcm::VR::US);
  de.SetByteValue(reinterpret_cast<const char*>(&v), 2);
  return de;
}

// Decimal strings of at most 16 characters each, backslash-separated (DS).
std::string decimalString(std::initializer_list<double> values) {
  std::string out;
  for (const double v : values) {
    std::ostringstream s;
    s.precision(10);
    s << v;
    std::string t = s.str();
    if (t.size() > 16) {
      s.str("");
      s.precision(8);
      s << v;
      t = s.str();
    }
    out += (out.empty() ? "" : "\\") + t;
  }
  return out;
}

// A sequence of the given items, each a data set.
gdcm::DataElement sequence(uint16_t group, uint16_t element, const std::vector<gdcm::DataSet>& items) {
  gdcm::SmartPointer<gdcm::SequenceOfItems> sq = new gdcm::SequenceOfItems;
  sq->SetLengthToUndefined();
  for (const gdcm::DataSet& d : items) {
    gdcm::Item item;
    item.SetVLToUndefined();
    item.SetNestedDataSet(d);
    sq->AddItem(item);
  }
  gdcm::DataElement de(gdcm::Tag(group, element));
  de.SetVR(gdcm::VR::SQ);
  de.SetValue(*sq);
  de.SetVLToUndefined();
  return de;
}

gdcm::DataSet itemOf(std::initializer_list<gdcm::DataElement> elements) {
  gdcm::DataSet d;
  for (const gdcm::DataElement& e : elements) d.Replace(e);
  return d;
}

std::string uidFor(const std::string& base, int n) { return base + "." + std::to_string(n); }

// The patient, study and series elements every file of a study holds.
void putStudy(gdcm::DataSet& ds, const DicomStudy& study, const std::string& seriesUid, int seriesNumber, const std::string& seriesDescription,
              const std::string& modality) {
  ds.Replace(text(0x0008, 0x0020, gdcm::VR::DA, study.date));
  ds.Replace(text(0x0008, 0x0030, gdcm::VR::TM, "101500"));
  ds.Replace(text(0x0008, 0x0050, gdcm::VR::SH, "A" + study.patientId));
  ds.Replace(text(0x0008, 0x0060, gdcm::VR::CS, modality));
  ds.Replace(text(0x0008, 0x1030, gdcm::VR::LO, study.description));
  ds.Replace(text(0x0008, 0x103e, gdcm::VR::LO, seriesDescription));
  ds.Replace(text(0x0010, 0x0010, gdcm::VR::PN, study.patientName));
  ds.Replace(text(0x0010, 0x0020, gdcm::VR::LO, study.patientId));
  ds.Replace(text(0x0020, 0x000d, gdcm::VR::UI, study.uid));
  ds.Replace(text(0x0020, 0x000e, gdcm::VR::UI, seriesUid));
  ds.Replace(text(0x0020, 0x0010, gdcm::VR::SH, "1"));
  ds.Replace(text(0x0020, 0x0011, gdcm::VR::IS, std::to_string(seriesNumber)));
}

void check(bool ok, const std::string& what) {
  if (!ok) throw std::runtime_error("dicom_writer: " + what);
}

// A greyscale pixel module of signed 16-bit pixels, and @p pixels as its Pixel Data.
void putPixels(gdcm::DataSet& ds, const glm::ivec2& size, const std::vector<int16_t>& pixels) {
  ds.Replace(us(0x0028, 0x0002, 1));
  ds.Replace(text(0x0028, 0x0004, gdcm::VR::CS, "MONOCHROME2"));
  ds.Replace(us(0x0028, 0x0010, uint16_t(size.y)));
  ds.Replace(us(0x0028, 0x0011, uint16_t(size.x)));
  ds.Replace(us(0x0028, 0x0100, 16));
  ds.Replace(us(0x0028, 0x0101, 16));
  ds.Replace(us(0x0028, 0x0102, 15));
  ds.Replace(us(0x0028, 0x0103, 1));
  gdcm::DataElement data(gdcm::Tag(0x7fe0, 0x0010));
  data.SetVR(gdcm::VR::OW);
  data.SetByteValue(reinterpret_cast<const char*>(pixels.data()), uint32_t(pixels.size() * 2));
  ds.Replace(data);
}

// The file meta information of SOP instance @p sop of class @p sopClass, in transfer syntax @p syntax
// (GDCM deflates the data set for the deflated one), and the file written.
void writeFile(gdcm::Writer& w, const std::string& path, const std::string& sopClass, const std::string& sop,
               const std::string& syntax = "1.2.840.10008.1.2.1") {
  gdcm::FileMetaInformation& meta = w.GetFile().GetHeader();
  const gdcm::TransferSyntax ts(gdcm::TransferSyntax::GetTSType(syntax.c_str()));
  check(ts.IsValid(), "unknown transfer syntax " + syntax);
  meta.SetDataSetTransferSyntax(ts);
  meta.Replace(text(0x0002, 0x0002, gdcm::VR::UI, sopClass));
  meta.Replace(text(0x0002, 0x0003, gdcm::VR::UI, sop));
  std::filesystem::create_directories(std::filesystem::path(path).parent_path());
  w.SetFileName(path.c_str());
  check(w.Write(), "cannot write " + path);
}

}  // namespace

glm::dvec3 DicomImage::at(int i, int j) const {
  const glm::dvec3 r(cosines[0], cosines[1], cosines[2]), c(cosines[3], cosines[4], cosines[5]);
  return position + double(i) * spacing.x * r + double(j) * spacing.y * c;
}

void sampleField(DicomImage* image, const std::function<double(const glm::dvec3&)>& hu) {
  image->pixels.resize(size_t(image->size.x) * size_t(image->size.y));
  for (int j = 0; j < image->size.y; ++j)
    for (int i = 0; i < image->size.x; ++i) {
      const double stored = std::round((hu(image->at(i, j)) - image->intercept) / image->slope);
      image->pixels[size_t(i) + size_t(image->size.x) * size_t(j)] = int16_t(std::clamp(stored, -32768.0, 32767.0));
    }
}

void writeCtImage(const std::string& path, const DicomStudy& study, const DicomImage& image) {
  gdcm::Trace::WarningOff();
  gdcm::Writer w;
  gdcm::DataSet& ds = w.GetFile().GetDataSet();
  const std::string sopClass = gdcm::MediaStorage::GetMSString(gdcm::MediaStorage::CTImageStorage);
  const std::string sop = uidFor(image.seriesUid, image.instance);
  ds.Replace(text(0x0008, 0x0008, gdcm::VR::CS, image.imageType));
  ds.Replace(text(0x0008, 0x0016, gdcm::VR::UI, sopClass));
  ds.Replace(text(0x0008, 0x0018, gdcm::VR::UI, sop));
  putStudy(ds, study, image.seriesUid, image.seriesNumber, image.seriesDescription, "CT");
  ds.Replace(text(0x0018, 0x0050, gdcm::VR::DS, decimalString({image.thickness})));
  if (image.tilt != 0.0) ds.Replace(text(0x0018, 0x1120, gdcm::VR::DS, decimalString({image.tilt})));
  ds.Replace(text(0x0018, 0x5100, gdcm::VR::CS, "HFS"));
  ds.Replace(text(0x0020, 0x0013, gdcm::VR::IS, std::to_string(image.instance)));
  ds.Replace(text(0x0020, 0x0032, gdcm::VR::DS, decimalString({image.position.x, image.position.y, image.position.z})));
  const double* c = image.cosines;
  ds.Replace(text(0x0020, 0x0037, gdcm::VR::DS, decimalString({c[0], c[1], c[2], c[3], c[4], c[5]})));
  ds.Replace(text(0x0028, 0x0030, gdcm::VR::DS, decimalString({image.spacing.y, image.spacing.x})));
  ds.Replace(text(0x0028, 0x1052, gdcm::VR::DS, decimalString({image.intercept})));
  ds.Replace(text(0x0028, 0x1053, gdcm::VR::DS, decimalString({image.slope})));
  check(image.pixels.size() == size_t(image.size.x) * size_t(image.size.y), "pixels of another size than the image");
  putPixels(ds, image.size, image.pixels);
  writeFile(w, path, sopClass, sop, image.transferSyntax);
}

void writeEnhancedCt(const std::string& path, const DicomStudy& study, const std::vector<DicomImage>& frames) {
  check(!frames.empty(), "no frames");
  gdcm::Trace::WarningOff();
  const DicomImage& f0 = frames.front();
  gdcm::Writer w;
  gdcm::DataSet& ds = w.GetFile().GetDataSet();
  const std::string sopClass = gdcm::MediaStorage::GetMSString(gdcm::MediaStorage::EnhancedCTImageStorage);
  const std::string sop = uidFor(f0.seriesUid, 1);
  ds.Replace(text(0x0008, 0x0008, gdcm::VR::CS, f0.imageType));
  ds.Replace(text(0x0008, 0x0016, gdcm::VR::UI, sopClass));
  ds.Replace(text(0x0008, 0x0018, gdcm::VR::UI, sop));
  putStudy(ds, study, f0.seriesUid, f0.seriesNumber, f0.seriesDescription, "CT");
  ds.Replace(text(0x0020, 0x0013, gdcm::VR::IS, "1"));
  ds.Replace(text(0x0028, 0x0008, gdcm::VR::IS, std::to_string(frames.size())));
  const double* c = f0.cosines;
  gdcm::DataSet shared = itemOf({sequence(0x0028, 0x9110, {itemOf({text(0x0028, 0x0030, gdcm::VR::DS, decimalString({f0.spacing.y, f0.spacing.x})),
                                                                     text(0x0018, 0x0050, gdcm::VR::DS, decimalString({f0.thickness}))})}),
                                 sequence(0x0020, 0x9116, {itemOf({text(0x0020, 0x0037, gdcm::VR::DS, decimalString({c[0], c[1], c[2], c[3], c[4], c[5]}))})})});
  ds.Replace(sequence(0x5200, 0x9229, {shared}));
  std::vector<gdcm::DataSet> perFrame;
  std::vector<int16_t> all;
  for (const DicomImage& f : frames) {
    check(f.size == f0.size && f.pixels.size() == size_t(f0.size.x) * size_t(f0.size.y), "frames of two sizes");
    perFrame.push_back(itemOf({sequence(0x0020, 0x9113, {itemOf({text(0x0020, 0x0032, gdcm::VR::DS, decimalString({f.position.x, f.position.y, f.position.z}))})}),
                               sequence(0x0028, 0x9145, {itemOf({text(0x0028, 0x1052, gdcm::VR::DS, decimalString({f.intercept})),
                                                                 text(0x0028, 0x1053, gdcm::VR::DS, decimalString({f.slope})),
                                                                 text(0x0028, 0x1054, gdcm::VR::LO, "HU")})})}));
    all.insert(all.end(), f.pixels.begin(), f.pixels.end());
  }
  ds.Replace(sequence(0x5200, 0x9230, perFrame));
  putPixels(ds, f0.size, all);
  writeFile(w, path, sopClass, sop);
}

void writeStructuredReport(const std::string& path, const DicomStudy& study, const std::string& seriesUid) {
  gdcm::Trace::WarningOff();
  gdcm::Writer w;
  gdcm::DataSet& ds = w.GetFile().GetDataSet();
  const std::string sopClass = "1.2.840.10008.5.1.4.1.1.88.11";  // Basic Text SR
  const std::string sop = uidFor(seriesUid, 1);
  ds.Replace(text(0x0008, 0x0016, gdcm::VR::UI, sopClass));
  ds.Replace(text(0x0008, 0x0018, gdcm::VR::UI, sop));
  putStudy(ds, study, seriesUid, 99, "Dose report", "SR");
  ds.Replace(text(0x0040, 0xa040, gdcm::VR::CS, "CONTAINER"));
  writeFile(w, path, sopClass, sop);
}

void writeDicomdir(const std::string& root, const std::vector<std::string>& files) {
  gdcm::Trace::WarningOff();
  struct Entry {
    std::string patient, study, series, sopClass, sop, id;
  };
  std::vector<Entry> entries;
  for (const std::string& f : files) {
    gdcm::Reader r;
    r.SetFileName((std::filesystem::path(root) / f).string().c_str());
    check(r.Read(), "cannot read " + f);
    gdcm::StringFilter sf;
    sf.SetFile(r.GetFile());
    auto get = [&](uint16_t g, uint16_t e) {
      std::string v = sf.ToString(gdcm::Tag(g, e));
      while (!v.empty() && (v.back() == ' ' || v.back() == '\0')) v.pop_back();
      return v;
    };
    std::string id = f;
    std::replace(id.begin(), id.end(), '/', '\\');
    entries.push_back({get(0x0010, 0x0020), get(0x0020, 0x000d), get(0x0020, 0x000e), get(0x0008, 0x0016), get(0x0008, 0x0018), id});
  }
  // Depth first, patient > study > series > image, as CD writers order their records.
  std::stable_sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) {
    return std::tie(a.patient, a.study, a.series) < std::tie(b.patient, b.study, b.series);
  });
  std::vector<gdcm::DataSet> records;
  std::string patient = "\x01", study = "\x01", series = "\x01";
  for (const Entry& e : entries) {
    if (e.patient != patient)
      records.push_back(itemOf({text(0x0004, 0x1430, gdcm::VR::CS, "PATIENT"), text(0x0010, 0x0020, gdcm::VR::LO, patient = e.patient)}));
    if (e.study != study) records.push_back(itemOf({text(0x0004, 0x1430, gdcm::VR::CS, "STUDY"), text(0x0020, 0x000d, gdcm::VR::UI, study = e.study)}));
    if (e.series != series)
      records.push_back(itemOf({text(0x0004, 0x1430, gdcm::VR::CS, "SERIES"), text(0x0020, 0x000e, gdcm::VR::UI, series = e.series)}));
    const bool sr = e.sopClass.rfind("1.2.840.10008.5.1.4.1.1.88.", 0) == 0;
    records.push_back(itemOf({text(0x0004, 0x1430, gdcm::VR::CS, sr ? "SR DOCUMENT" : "IMAGE"), text(0x0004, 0x1500, gdcm::VR::CS, e.id),
                              text(0x0004, 0x1510, gdcm::VR::UI, e.sopClass), text(0x0004, 0x1511, gdcm::VR::UI, e.sop),
                              text(0x0004, 0x1512, gdcm::VR::UI, "1.2.840.10008.1.2.1")}));
  }
  gdcm::Writer w;
  gdcm::DataSet& ds = w.GetFile().GetDataSet();
  ds.Replace(text(0x0004, 0x1130, gdcm::VR::CS, "HYBTEST"));
  ds.Replace(sequence(0x0004, 0x1220, records));
  writeFile(w, (std::filesystem::path(root) / "DICOMDIR").string(), "1.2.840.10008.1.3.10", "1.2.826.0.1.3680043.8.498.99");
}

std::vector<DicomImage> writeSeries(const std::string& dir, const std::string& prefix, const DicomStudy& study, DicomImage model,
                                    const std::vector<glm::dvec3>& positions, const std::function<double(const glm::dvec3&)>& hu) {
  std::filesystem::create_directories(dir);
  std::vector<DicomImage> out;
  const size_t n = positions.size();
  for (size_t k = 0; k < n; ++k) {
    DicomImage image = model;
    image.instance = int(k + 1);
    image.position = positions[k];
    sampleField(&image, hu);
    // Files named in reverse (and without extension, as on a CD): their names do not sort by position.
    writeCtImage(dir + "/" + prefix + std::to_string(n - k), study, image);
    out.push_back(std::move(image));
  }
  return out;
}

}  // namespace hyb::test
